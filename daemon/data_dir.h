// Datasets confined to the data directory: SWEEP names a directory relative to
// recording.data_dir, and nothing a client sends may write outside it or over what is there.
#pragma once

#include <string>

namespace idm::daemon {

// Creates data_dir/relative as a new, empty directory and returns its path. `relative` must be a
// relative path of plain names (no "..", ".", empty component or leading '/'); its parents are
// walked from data_dir with openat(O_NOFOLLOW | O_DIRECTORY), so that a symlink anywhere below
// data_dir is refused rather than followed, and missing parents are created (mode 0755). The last
// component must not exist: an existing dataset (or any file of that name) is refused, never
// overwritten. On failure returns "" and sets `error` to a sentence naming the path and why.
std::string create_dataset_dir(const std::string& data_dir, const std::string& relative,
                               std::string& error);

}  // namespace idm::daemon
