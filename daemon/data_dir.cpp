#include "daemon/data_dir.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <vector>

namespace idm::daemon {

namespace {

// Closes the descriptor it holds when it goes out of scope.
struct Fd {
  int fd = -1;
  explicit Fd(int f) : fd(f) {}
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
  void reset(int f) {
    if (fd >= 0) ::close(fd);
    fd = f;
  }
};

bool split_relative(const std::string& relative, std::vector<std::string>& parts,
                    std::string& why) {
  if (relative.empty()) {
    why = "is empty";
    return false;
  }
  if (relative.front() == '/') {
    why = "is absolute: give a path relative to recording.data_dir";
    return false;
  }
  std::size_t start = 0;
  for (std::size_t i = 0; i <= relative.size(); ++i) {
    if (i < relative.size() && relative[i] != '/') continue;
    const std::string part = relative.substr(start, i - start);
    start = i + 1;
    if (part.empty() && i == relative.size() && !parts.empty()) break;  // a trailing '/'
    if (part.empty() || part == "." || part == "..") {
      why = "has a '" + part + "' component: only plain names are allowed (no '..', '.' or '//')";
      return false;
    }
    if (part.size() > 255) {
      why = "has a component longer than 255 bytes";
      return false;
    }
    parts.push_back(part);
  }
  return true;
}

}  // namespace

recording::DirFd create_dataset_dir(const recording::DirFd& data_dir, const std::string& shown,
                                    const std::string& relative, std::string& path,
                                    std::string& error) {
  std::vector<std::string> parts;
  std::string why;
  if (!split_relative(relative, parts, why)) {
    error = "dataset directory '" + relative + "' " + why;
    return {};
  }
  if (!data_dir.valid()) {
    error = "recording.data_dir " + shown + " could not be opened";
    return {};
  }
  Fd dir(::dup(data_dir.get()));
  std::string walked = shown;
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    const char* name = parts[i].c_str();
    walked += "/" + parts[i];
    int next = ::openat(dir.fd, name, O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
    if (next < 0 && errno == ENOENT) {
      if (::mkdirat(dir.fd, name, 0755) != 0 && errno != EEXIST) {
        error = "cannot create " + walked + ": " + std::strerror(errno);
        return {};
      }
      next = ::openat(dir.fd, name, O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
    }
    if (next < 0) {
      const int e = errno;
      error = walked + (e == ELOOP || e == ENOTDIR
                            ? std::string(" is a symbolic link or not a directory: refused "
                                          "(datasets stay inside recording.data_dir)")
                            : ": " + std::string(std::strerror(e)));
      return {};
    }
    dir.reset(next);
  }
  walked += "/" + parts.back();
  if (::mkdirat(dir.fd, parts.back().c_str(), 0755) != 0) {
    const int e = errno;
    error = walked + (e == EEXIST ? std::string(" already exists: a dataset is never overwritten; "
                                                "choose a new name")
                                  : ": " + std::string(std::strerror(e)));
    return {};
  }
  const int made =
      ::openat(dir.fd, parts.back().c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  if (made < 0) {
    error = walked + ": swapped for a link or removed as it was made: refused";
    return {};
  }
  // Sync the parent so the new directory survives a crash with the first trial.
  ::fsync(dir.fd);
  path = walked;
  return recording::DirFd(made);
}

}  // namespace idm::daemon
