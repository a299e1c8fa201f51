// An axis's reference kept across restarts (the axis key `reference_file`): what a restarted
// idmd needs to read the same positions again, and what proves that it may. The reference is the
// offset from the device's count to the position (the link's counts after a lost count, and the
// positioner's metres), valid only while the device's count epoch is the one it was found in: a
// device that restarted its count, a simulated one (which lives in idmd), or one that reports no
// epoch never restores it. Written whole or not at all (recording::write_file_durably).
#pragma once

#include <cstdint>
#include <string>

#include "drivers/link.h"

namespace idm::daemon {

struct SavedReference {
  bool referenced = false;
  drivers::CountOrigin origin;  // the count's epoch and the link's offset in counts
  double offset_m = 0;          // the positioner's offset (control::MotionStatus::offset_m)
  // The user offset (POSition:SET / POSition:OFFSet, Axis::user_offset_m): kept with the
  // reference, since it means something only while the reference does. Optional in the file
  // (0 when absent: files written before it).
  double user_offset_m = 0;
  bool operator==(const SavedReference& o) const {
    return referenced == o.referenced && origin.has_epoch == o.origin.has_epoch &&
           origin.epoch == o.origin.epoch && origin.offset_counts == o.origin.offset_counts &&
           offset_m == o.offset_m && user_offset_m == o.user_offset_m;
  }
};

// The file's text: YAML, the offset exact (17 significant digits).
std::string reference_text(const SavedReference& r, const std::string& axis);
// Reads a file written by save_reference. Throws model::InputError naming the file, the line and
// the key (a missing key, a wrong type, a number out of range).
SavedReference load_reference(const std::string& path);
// Throws std::system_error naming the file; the old file stays as it was then.
void save_reference(const std::string& path, const SavedReference& r, const std::string& axis);

// Whether `saved` holds for a device whose count origin is now `now`: "" when it does, else why
// not (in words, for the log).
std::string reference_holds(const SavedReference& saved, const drivers::CountOrigin& now);

}  // namespace idm::daemon
