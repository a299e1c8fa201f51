// Checked reads of YAML scalars: every error names the file, the line, the key and the range.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstddef>
#include <string>
#include <vector>

#include "model/range.h"

namespace idm::model {

// "FILE:LINE: KEY: MESSAGE" (LINE 1-based, omitted when the node has no mark).
std::string located(const std::string& file, const YAML::Node& node, const std::string& key,
                    const std::string& message);

// Reads a finite double within [lo, hi] (or (lo, hi] when lo_open). Throws InputError.
double read_double(const YAML::Node& node, const std::string& file, const std::string& key,
                   double lo, double hi, bool lo_open = false);
long read_integer(const YAML::Node& node, const std::string& file, const std::string& key, long lo,
                  long hi);
bool read_bool(const YAML::Node& node, const std::string& file, const std::string& key);
std::string read_string(const YAML::Node& node, const std::string& file, const std::string& key);

// "unknown key, did you mean 'max_retries'? allowed a, b, c" (`what`: "key", "section",
// "parameter"); the suggestion is the allowed name nearest to `given` (by edits, case ignored) when
// it is near enough to be a typo (at most a third of its letters, and at most 3), else none.
std::string unknown_name(const std::string& given, const std::vector<std::string>& allowed,
                         const std::string& what = "key");

// How large a YAML document may be: in bytes, and in nodes as its readers see it, every alias
// expanded (an "alias bomb" of a few hundred bytes expands nine-fold per level). The defaults fit
// a configuration, a stage or a calibration many times over; a sweep's plan.yaml (a line per
// planned cell) asks for more.
struct YamlLimits {
  std::size_t max_bytes = std::size_t{1} << 20;
  std::size_t max_nodes = 100000;
};

// Loads a YAML file; a missing file, a file that is not a regular file (a FIFO is refused at once,
// never waited on), a file or document past `limits`, a syntax error (a tab in the indentation
// said so), a key that appears twice in one map (both lines named), a key that is not a plain name
// (a map, a list or null as a key) or nesting deeper than 32 levels becomes InputError with the
// file and line.
YAML::Node load_yaml_file(const std::string& path, const YamlLimits& limits = {});
// The same for text already in memory; `name` stands for the file in messages.
YAML::Node load_yaml_text(const std::string& text, const std::string& name,
                          const YamlLimits& limits = {});
// Those checks on a document already parsed (duplicate keys name both lines).
void require_unique_keys(const YAML::Node& root, const std::string& file,
                         const YamlLimits& limits = {});

// The whole of a regular file of at most max_bytes. A FIFO, a device or a directory is refused
// without waiting on it, and so is a larger file; InputError names the file and the limit.
std::string read_regular_file(const std::string& path, std::size_t max_bytes);

}  // namespace idm::model
