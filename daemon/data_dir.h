// Datasets confined to the data directory: SWEEP names a directory relative to
// recording.data_dir, and nothing a client sends may write outside it or over what is there.
#pragma once

#include <string>

#include "recording/durable_file.h"

namespace idm::daemon {

// Creates `relative` below the data directory held open as `data_dir` (its path `shown` for
// messages) as a new, empty directory and returns it held open, with its path in `path`.
// `relative` must be a relative path of plain names (no "..", ".", empty component or leading
// '/'); its parents are walked from data_dir with openat(O_NOFOLLOW | O_DIRECTORY), so that a
// symlink anywhere below data_dir is refused rather than followed, and missing parents are
// created (mode 0755). The last component must not exist: an existing dataset (or any file of
// that name) is refused, never overwritten; it is opened with O_NOFOLLOW right after it is made,
// and everything the recorder writes goes below that descriptor (no path is walked again). On
// failure returns an invalid DirFd and sets `error` to a sentence naming the path and why.
recording::DirFd create_dataset_dir(const recording::DirFd& data_dir, const std::string& shown,
                                    const std::string& relative, std::string& path,
                                    std::string& error);

}  // namespace idm::daemon
