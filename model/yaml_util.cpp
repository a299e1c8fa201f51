#include "model/yaml_util.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <vector>

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
  switch (parse_decimal(text, value)) {
    case NumberText::Ok:
      break;
    case NumberText::NotANumber:
      throw InputError(located(file, node, key, "'" + text + "' is not a number"));
    case NumberText::NotFinite:
      throw InputError(located(file, node, key, "must be finite, " + range_text(lo, hi, lo_open)));
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

// Levenshtein distance, case ignored.
std::size_t edits(const std::string& a, const std::string& b) {
  const auto lower = [](char c) {
    return static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  };
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min(
          {row[j] + 1, row[j - 1] + 1, diagonal + (lower(a[i - 1]) == lower(b[j - 1]) ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

}  // namespace

std::string unknown_name(const std::string& given, const std::vector<std::string>& allowed,
                         const std::string& what) {
  std::string best, list;
  std::size_t best_edits = std::min<std::size_t>(3, std::max<std::size_t>(1, given.size() / 3)) + 1;
  for (const std::string& a : allowed) {
    list += (list.empty() ? "" : ", ") + a;
    if (given.size() > 64) continue;  // no suggestion for a long word: no quadratic work on it
    if (const std::size_t e = edits(given, a); e < best_edits) {
      best_edits = e;
      best = a;
    }
  }
  std::string out = "unknown " + what + ", ";
  if (!best.empty()) out += "did you mean '" + best + "'? ";
  return out + "allowed " + list;
}

namespace {

constexpr int kMaxYamlDepth = 32;

// What every reader of a section takes for granted: every key is a plain name (a scalar, not a
// map, a list or nothing) and appears once in its map, and the document is a tree of bounded
// depth (an alias to a node that holds it would be endless) and of bounded size counted as its
// readers see it, every alias expanded. The path in messages is built only for a message.
class DocumentCheck {
 public:
  DocumentCheck(const std::string& file, const YamlLimits& limits) : file_(file), limits_(limits) {}

  void check(const YAML::Node& node, int depth) {
    if (++nodes_ > limits_.max_nodes)
      fail(node, "the document expands to more than " + std::to_string(limits_.max_nodes) +
                     " nodes with its aliases resolved (an alias bomb?); refused");
    if (depth > kMaxYamlDepth)
      fail(node, "nested deeper than " + std::to_string(kMaxYamlDepth) +
                     " levels (an alias to a node that holds it?)");
    if (node.IsSequence()) {
      for (std::size_t i = 0; i < node.size(); ++i) {
        path_.push_back("[" + std::to_string(i) + "]");
        check(node[i], depth + 1);
        path_.pop_back();
      }
      return;
    }
    if (!node.IsMap()) return;
    std::map<std::string, int> seen;  // key -> 1-based line of its first appearance
    for (const auto& kv : node) {
      if (!kv.first.IsScalar()) {
        path_.emplace_back(".(key)");
        fail(kv.first, "a key must be a plain name, not a map, a list or nothing");
      }
      const std::string& key = kv.first.Scalar();
      const int line = kv.first.Mark().line + 1;
      path_.push_back((path_.empty() ? "" : ".") + key);
      const auto [it, fresh] = seen.emplace(key, line);
      if (!fresh)
        fail(kv.first, "duplicate key: also at line " + std::to_string(it->second) +
                           " (YAML would silently keep one of them; remove the other)");
      check(kv.second, depth + 1);
      path_.pop_back();
    }
  }

 private:
  [[noreturn]] void fail(const YAML::Node& node, const std::string& message) const {
    std::string path;
    for (const std::string& p : path_) path += p;
    if (!path.empty() && path[0] == '.') path.erase(0, 1);
    throw InputError(located(file_, node, path.empty() ? "(document)" : path, message));
  }

  const std::string& file_;
  const YamlLimits& limits_;
  std::vector<std::string> path_;
  std::size_t nodes_ = 0;
};

// YAML forbids tabs in indentation, and yaml-cpp's message does not say so: "; the line is
// indented with a tab ..." when the failing line (or the one before it) is.
std::string tab_hint(const std::string& text, int line0) {
  std::size_t start = 0;
  for (int l = 0; l < line0 - 1 && start != std::string::npos; ++l) {
    start = text.find('\n', start);
    if (start != std::string::npos) ++start;
  }
  for (int l = std::max(0, line0 - 1);
       l <= line0 && start != std::string::npos && start < text.size(); ++l) {
    for (std::size_t i = start; i < text.size() && (text[i] == ' ' || text[i] == '\t'); ++i)
      if (text[i] == '\t')
        return "; line " + std::to_string(l + 1) +
               " is indented with a tab: YAML allows only spaces for indentation";
    start = text.find('\n', start);
    if (start != std::string::npos) ++start;
  }
  return {};
}

}  // namespace

void require_unique_keys(const YAML::Node& root, const std::string& file,
                         const YamlLimits& limits) {
  DocumentCheck(file, limits).check(root, 0);
}

YAML::Node load_yaml_text(const std::string& text, const std::string& name,
                          const YamlLimits& limits) {
  if (text.size() > limits.max_bytes)
    throw InputError(name + ": " + std::to_string(text.size()) + " bytes, more than the " +
                     std::to_string(limits.max_bytes) + " allowed for this file; refused");
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw InputError(name + ":" + std::to_string(e.mark.line + 1) +
                     ": YAML syntax error: " + e.msg + tab_hint(text, e.mark.line));
  }
  require_unique_keys(root, name, limits);
  return root;
}

YAML::Node load_yaml_file(const std::string& path, const YamlLimits& limits) {
  return load_yaml_text(read_regular_file(path, limits.max_bytes), path, limits);
}

std::string read_regular_file(const std::string& path, std::size_t max_bytes) {
  // O_NONBLOCK: opening a FIFO for reading would wait for a writer; fstat then refuses it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
  if (fd < 0) throw InputError(path + ": cannot open file (" + std::strerror(errno) + ")");
  struct Closer {
    int fd;
    explicit Closer(int f) : fd(f) {}
    Closer(const Closer&) = delete;
    Closer& operator=(const Closer&) = delete;
    Closer(Closer&&) = delete;
    Closer& operator=(Closer&&) = delete;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat info {};
  if (::fstat(fd, &info) != 0)
    throw InputError(path + ": cannot read file (" + std::strerror(errno) + ")");
  if (!S_ISREG(info.st_mode))
    throw InputError(path + ": not a regular file (" +
                     (S_ISFIFO(info.st_mode)  ? "a FIFO"
                      : S_ISDIR(info.st_mode) ? "a directory"
                                              : "a device or socket") +
                     "), allowed: a regular file");
  const auto bytes_text = [](std::size_t bytes) {
    return std::to_string(bytes) + " bytes (" + std::to_string(bytes >> 20) + " MiB)";
  };
  const auto size = static_cast<std::size_t>(info.st_size);
  if (size > max_bytes)
    throw InputError(path + ": " + bytes_text(size) + ", more than the reader takes in one file, " +
                     "allowed at most " + bytes_text(max_bytes));
  std::string text(size, '\0');
  std::size_t got = 0;
  while (got < text.size()) {  // the file may have shrunk meanwhile
    const ssize_t n = ::read(fd, text.data() + got, text.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw InputError(path + ": cannot read file (" + std::strerror(errno) + ")");
    if (n == 0) break;
    got += static_cast<std::size_t>(n);
  }
  text.resize(got);
  return text;
}

}  // namespace idm::model
