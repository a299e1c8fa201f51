// Files that survive a crash whole or not at all: written to a temporary name in their directory,
// fsynced, renamed over the final name, and the directory fsynced. The dataset writer, the
// daemon's calibration and reference files, and every report of the analysis write through these.
//
// Nothing here follows a symbolic link another user may have planted: the temporary file is
// created new (O_EXCL | O_NOFOLLOW, a stale one removed first), the rename replaces a link at the
// final name rather than writing through it, and writes below a directory held open (DirFd) walk
// every component with openat(O_NOFOLLOW), so a directory swapped for a link after it was opened
// is never followed.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>

namespace idm::recording {

// A directory held open (closed when it goes).
class DirFd {
 public:
  DirFd() = default;
  explicit DirFd(int fd) : fd_(fd) {}
  ~DirFd() { reset(); }
  DirFd(DirFd&& o) noexcept : fd_(o.fd_) { o.fd_ = -1; }
  DirFd& operator=(DirFd&& o) noexcept {
    if (this != &o) {
      reset();
      fd_ = o.fd_;
      o.fd_ = -1;
    }
    return *this;
  }
  DirFd(const DirFd&) = delete;
  DirFd& operator=(const DirFd&) = delete;
  int get() const { return fd_; }
  bool valid() const { return fd_ >= 0; }
  void reset();

  // Opens `path` (which must be a directory; a link to one is followed only when `follow`).
  // Throws std::system_error naming it.
  static DirFd open(const std::filesystem::path& path, bool follow = true);

 private:
  int fd_ = -1;
};

// Writes `content` to `final_path`: a reader sees the old file or the new one, never part of one.
// On failure the temporary file is removed and `final_path` is as it was. Throws std::system_error
// naming the file.
void write_file_durably(const std::filesystem::path& final_path, std::string_view content);

// The same below a directory held open: `relative` is a relative path of plain names (no "..",
// ".", empty component); its directories are created when missing and never followed when they
// are links. `shown` stands for the directory in messages.
void write_file_durably_at(const DirFd& dir, const std::string& relative, std::string_view content,
                           const std::string& shown);

// Removes the file `relative` below `dir` if it is there (a link in the way is never followed);
// never throws.
void remove_file_at(const DirFd& dir, const std::string& relative) noexcept;

// Creates `dir` (and missing parents) and makes the new entries durable. Throws std::system_error.
void create_directory_durably(const std::filesystem::path& dir);

// Opens (creating it when missing, durably) the directory `relative` below `dir`, never
// following a link. Throws std::system_error naming it.
DirFd open_directory_at(const DirFd& dir, const std::string& relative, const std::string& shown);

}  // namespace idm::recording
