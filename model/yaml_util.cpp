#include "model/yaml_util.h"

#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include "model/stage.h"

namespace idm::model {

std::string located(const std::string& file, const YAML::Node& node, const std::string& key,
                    const std::string& message) {
  std::ostringstream out;
  out << file;
  if (node.IsDefined() && node.Mark().line >= 0) out << ":" << node.Mark().line + 1;
  out << ": " << key << ": " << message;
  return out.str();
}

namespace {
std::string range_text(double lo, double hi, bool lo_open) {
  std::ostringstream out;
  out.precision(6);
  out << "allowed " << (lo_open ? "(" : "[") << lo << ", " << hi << "]";
  return out.str();
}
}  // namespace

double read_double(const YAML::Node& node, const std::string& file, const std::string& key,
                   double lo, double hi, bool lo_open) {
  if (!node.IsScalar()) throw InputError(located(file, node, key, "expected a number"));
  double value = 0.0;
  const std::string& text = node.Scalar();
  for (const char* special : {".nan", ".NaN", ".NAN", ".inf", ".Inf", ".INF", "-.inf", "-.Inf",
                              "-.INF", "nan", "inf", "-inf", "NaN"})
    if (text == special)
      throw InputError(located(file, node, key, "must be finite, " + range_text(lo, hi, lo_open)));
  try {
    std::size_t used = 0;
    value = std::stod(text, &used);
    if (used != text.size()) throw std::invalid_argument(text);
  } catch (const std::exception&) {
    throw InputError(located(file, node, key, "'" + text + "' is not a number"));
  }
  if (!std::isfinite(value))
    throw InputError(located(file, node, key, "must be finite, " + range_text(lo, hi, lo_open)));
  if (value < lo || value > hi || (lo_open && value == lo)) {
    std::ostringstream msg;
    msg.precision(9);
    msg << value << " is out of range, " << range_text(lo, hi, lo_open);
    throw InputError(located(file, node, key, msg.str()));
  }
  return value;
}

long read_integer(const YAML::Node& node, const std::string& file, const std::string& key, long lo,
                  long hi) {
  if (!node.IsScalar()) throw InputError(located(file, node, key, "expected an integer"));
  const std::string& text = node.Scalar();
  long value = 0;
  try {
    std::size_t used = 0;
    value = std::stol(text, &used);
    if (used != text.size()) throw std::invalid_argument(text);
  } catch (const std::exception&) {
    throw InputError(located(file, node, key, "'" + text + "' is not an integer"));
  }
  if (value < lo || value > hi) {
    throw InputError(located(file, node, key,
                             std::to_string(value) + " is out of range, allowed [" +
                                 std::to_string(lo) + ", " + std::to_string(hi) + "]"));
  }
  return value;
}

bool read_bool(const YAML::Node& node, const std::string& file, const std::string& key) {
  if (node.IsScalar()) {
    const std::string& t = node.Scalar();
    if (t == "true" || t == "yes" || t == "on") return true;
    if (t == "false" || t == "no" || t == "off") return false;
  }
  throw InputError(located(file, node, key, "expected true or false"));
}

std::string read_string(const YAML::Node& node, const std::string& file, const std::string& key) {
  if (!node.IsScalar()) throw InputError(located(file, node, key, "expected a string"));
  return node.Scalar();
}

namespace {

constexpr int kMaxYamlDepth = 32;

// What every reader of a section takes for granted: every key is a plain name (a scalar, not a
// map, a list or nothing) and appears once in its map, and the document is a tree of bounded
// depth (an alias to a node that holds it would be endless).
void check_document(const YAML::Node& node, const std::string& file, const std::string& path,
                    int depth) {
  if (depth > kMaxYamlDepth)
    throw InputError(located(file, node, path.empty() ? "(document)" : path,
                             "nested deeper than " + std::to_string(kMaxYamlDepth) +
                                 " levels (an alias to a node that holds it?)"));
  if (node.IsSequence()) {
    for (std::size_t i = 0; i < node.size(); ++i)
      check_document(node[i], file, path + "[" + std::to_string(i) + "]", depth + 1);
    return;
  }
  if (!node.IsMap()) return;
  std::map<std::string, int> seen;  // key -> 1-based line of its first appearance
  for (const auto& kv : node) {
    if (!kv.first.IsScalar())
      throw InputError(located(file, kv.first, path.empty() ? "(key)" : path + ".(key)",
                               "a key must be a plain name, not a map, a list or nothing"));
    const std::string key = kv.first.Scalar();
    const std::string full = path.empty() ? key : path + "." + key;
    const int line = kv.first.Mark().line + 1;
    const auto [it, fresh] = seen.emplace(key, line);
    if (!fresh)
      throw InputError(located(file, kv.first, full,
                               "duplicate key: also at line " + std::to_string(it->second) +
                                   " (YAML would silently keep one of them; remove the other)"));
    check_document(kv.second, file, full, depth + 1);
  }
}

}  // namespace

void require_unique_keys(const YAML::Node& root, const std::string& file) {
  check_document(root, file, "", 0);
}

YAML::Node load_yaml_text(const std::string& text, const std::string& name) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw InputError(name + ":" + std::to_string(e.mark.line + 1) +
                     ": YAML syntax error: " + e.msg);
  }
  require_unique_keys(root, name);
  return root;
}

YAML::Node load_yaml_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open file");
  std::stringstream text;
  text << in.rdbuf();
  return load_yaml_text(text.str(), path);
}

}  // namespace idm::model
