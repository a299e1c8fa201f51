#include "daemon/reference_file.h"

#include <cinttypes>
#include <cstdio>
#include <limits>

#include "daemon/instrument.h"
#include "model/stage.h"
#include "model/yaml_util.h"
#include "recording/durable_file.h"

namespace idm::daemon {

namespace {

// root[key], which must be there.
YAML::Node required(const YAML::Node& root, const char* key, const std::string& path) {
  const YAML::Node n = root[key];
  if (!n.IsDefined())
    throw model::InputError(model::located(path, root, key, "missing (the file is not idmd's)"));
  return n;
}

// The epoch as text: all 64 bits (a YAML integer reader stops at the signed range).
std::uint64_t read_epoch(const YAML::Node& root, const std::string& path) {
  const YAML::Node n = required(root, "count_epoch", path);
  const std::string text = model::read_string(n, path, "count_epoch");
  std::uint64_t value = 0;
  int used = 0;
  if (std::sscanf(text.c_str(), "%" SCNu64 "%n", &value, &used) != 1 ||
      static_cast<std::size_t>(used) != text.size() || text[0] == '-')
    throw model::InputError(model::located(
        path, n, "count_epoch", "expected an unsigned 64-bit integer, got '" + text + "'"));
  return value;
}

}  // namespace

std::string reference_text(const SavedReference& r, const std::string& axis) {
  char numbers[200];
  std::snprintf(numbers, sizeof numbers,
                "has_count_epoch: %s\ncount_epoch: \"%" PRIu64 "\"\noffset_counts: %" PRId64
                "\noffset_m: %.17g\nuser_offset_m: %.17g\n",
                r.origin.has_epoch ? "true" : "false", r.origin.epoch, r.origin.offset_counts,
                r.offset_m, r.user_offset_m);
  return "# idmd: the reference of axis " + axis +
         " (restored at start only while the device's count epoch is the same)\nreferenced: " +
         (r.referenced ? "true" : "false") + "\n" + numbers;
}

SavedReference load_reference(const std::string& path) {
  const YAML::Node root = model::load_yaml_file(path);
  if (!root.IsMap())
    throw model::InputError(model::located(path, root, "(top)", "expected a YAML map"));
  SavedReference r;
  r.referenced = model::read_bool(required(root, "referenced", path), path, "referenced");
  r.origin.has_epoch =
      model::read_bool(required(root, "has_count_epoch", path), path, "has_count_epoch");
  r.origin.epoch = read_epoch(root, path);
  constexpr long kMaxCounts = std::numeric_limits<long>::max();
  r.origin.offset_counts = model::read_integer(required(root, "offset_counts", path), path,
                                               "offset_counts", -kMaxCounts, kMaxCounts);
  r.offset_m = model::read_double(required(root, "offset_m", path), path, "offset_m", -100, 100);
  if (const YAML::Node u = root["user_offset_m"])
    r.user_offset_m =
        model::read_double(u, path, "user_offset_m", -kMaxUserOffsetM, kMaxUserOffsetM);
  return r;
}

void save_reference(const std::string& path, const SavedReference& r, const std::string& axis) {
  recording::write_file_durably(path, reference_text(r, axis));
}

std::string reference_holds(const SavedReference& saved, const drivers::CountOrigin& now) {
  if (!saved.referenced) return "it was not referenced when idmd stopped";
  if (!saved.origin.has_epoch || !now.has_epoch)
    return "the device reports no count epoch, so it cannot show that it kept its count";
  if (saved.origin.epoch != now.epoch)
    return "the device's count started over since (count epoch " +
           std::to_string(saved.origin.epoch) + ", now " + std::to_string(now.epoch) + ")";
  return "";
}

}  // namespace idm::daemon
