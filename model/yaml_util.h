// Checked reads of YAML scalars: every error names the file, the line, the key and the range.
#pragma once

#include <yaml-cpp/yaml.h>

#include <string>

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

// Loads a YAML file; a missing file, a syntax error, a key that appears twice in one map (both
// lines named), a key that is not a plain name (a map, a list or null as a key) or nesting deeper
// than 32 levels becomes InputError with the file and line.
YAML::Node load_yaml_file(const std::string& path);
// The same for text already in memory; `name` stands for the file in messages.
YAML::Node load_yaml_text(const std::string& text, const std::string& name);
// Those checks on a document already parsed (duplicate keys name both lines).
void require_unique_keys(const YAML::Node& root, const std::string& file);

}  // namespace idm::model
