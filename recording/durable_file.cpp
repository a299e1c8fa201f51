#include "recording/durable_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <string>
#include <system_error>
#include <vector>

namespace idm::recording {

namespace fs = std::filesystem;

namespace {

[[noreturn]] void throw_errno(int error, const std::string& what) {
  throw std::system_error(error, std::generic_category(), what);
}

// fsync of a directory, so that a rename or a new entry in it survives a crash. File systems that
// cannot sync a directory (EINVAL) are accepted.
void fsync_directory(const fs::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) throw_errno(errno, dir.string() + ": cannot open directory to sync it");
  if (::fsync(fd) != 0 && errno != EINVAL) {
    const int error = errno;
    ::close(fd);
    throw_errno(error, dir.string() + ": cannot sync directory");
  }
  ::close(fd);
}

// The components of a relative path of plain names; throws naming it otherwise.
std::vector<std::string> plain_components(const std::string& relative, const std::string& shown) {
  std::vector<std::string> parts;
  std::size_t start = 0;
  for (std::size_t i = 0; i <= relative.size(); ++i) {
    if (i < relative.size() && relative[i] != '/') continue;
    std::string part = relative.substr(start, i - start);
    start = i + 1;
    if (part.empty() || part == "." || part == "..")
      throw_errno(EINVAL, shown + "/" + relative + ": not a relative path of plain names");
    parts.push_back(std::move(part));
  }
  return parts;
}

void fsync_fd(int fd, const std::string& what) {
  if (::fsync(fd) != 0 && errno != EINVAL) throw_errno(errno, what + ": cannot sync");
}

// The directory `name` in `parent` (created when missing), never a link followed.
int child_directory(int parent, const std::string& name, const std::string& shown) {
  int fd = ::openat(parent, name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  if (fd < 0 && errno == ENOENT) {
    if (::mkdirat(parent, name.c_str(), 0755) != 0 && errno != EEXIST)
      throw_errno(errno, shown + ": cannot create directory");
    fsync_fd(parent, shown + "/..");
    fd = ::openat(parent, name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  }
  if (fd < 0)
    throw_errno(errno, shown + (errno == ELOOP || errno == ENOTDIR
                                    ? ": a symbolic link or not a directory; refused"
                                    : ": cannot open directory"));
  return fd;
}

// Writes `name` in the directory `dir` (a file name, no '/'): temporary name, fsync, rename,
// fsync of the directory.
void write_in_directory(int dir, const std::string& name, std::string_view content,
                        const std::string& shown) {
  const std::string tmp = "." + name + ".tmp";
  // A stale temporary (a crash), or a link planted in its place: removed, never written through.
  if (::unlinkat(dir, tmp.c_str(), 0) != 0 && errno != ENOENT)
    throw_errno(errno, shown + ": cannot remove the stale " + tmp);
  const int fd =
      ::openat(dir, tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
  if (fd < 0) throw_errno(errno, shown + ": cannot create " + tmp);
  auto fail = [&](int error, const std::string& what, bool close_fd) {
    if (close_fd) ::close(fd);
    ::unlinkat(dir, tmp.c_str(), 0);
    throw_errno(error, shown + ": " + what);
  };
  const char* data = content.data();
  std::size_t left = content.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, data, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      fail(errno, "cannot write " + tmp, true);
    }
    data += n;
    left -= static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) fail(errno, "cannot sync " + tmp, true);
  if (::close(fd) != 0) fail(errno, "cannot close " + tmp, false);
  if (::renameat(dir, tmp.c_str(), dir, name.c_str()) != 0)
    fail(errno, "cannot rename " + tmp + " to " + name, false);
  fsync_fd(dir, shown + ": its directory");
}

}  // namespace

void DirFd::reset() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

DirFd DirFd::open(const fs::path& path, bool follow) {
  const int fd = ::open(path.empty() ? "." : path.c_str(),
                        O_RDONLY | O_DIRECTORY | O_CLOEXEC | (follow ? 0 : O_NOFOLLOW));
  if (fd < 0) throw_errno(errno, path.string() + ": cannot open directory");
  return DirFd(fd);
}

void write_file_durably(const fs::path& final_path, std::string_view content) {
  const fs::path parent = final_path.parent_path();
  const int fd = ::open(parent.empty() ? "." : parent.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) throw_errno(errno, final_path.string() + ": cannot open its directory");
  const DirFd dir(fd);
  write_in_directory(dir.get(), final_path.filename().string(), content, final_path.string());
}

void write_file_durably_at(const DirFd& dir, const std::string& relative, std::string_view content,
                           const std::string& shown) {
  const std::vector<std::string> parts = plain_components(relative, shown);
  DirFd at(::dup(dir.get()));
  std::string walked = shown;
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    walked += "/" + parts[i];
    at = DirFd(child_directory(at.get(), parts[i], walked));
  }
  write_in_directory(at.get(), parts.back(), content, shown + "/" + relative);
}

void remove_file_at(const DirFd& dir, const std::string& relative) noexcept {
  try {
    const std::size_t slash = relative.rfind('/');
    if (slash == std::string::npos) {
      ::unlinkat(dir.get(), relative.c_str(), 0);
      return;
    }
    // The directories exist already (the file was written there): opening them creates nothing.
    const DirFd parent = open_directory_at(dir, relative.substr(0, slash), "");
    ::unlinkat(parent.get(), relative.substr(slash + 1).c_str(), 0);
  } catch (...) {
  }
}

DirFd open_directory_at(const DirFd& dir, const std::string& relative, const std::string& shown) {
  DirFd at(::dup(dir.get()));
  std::string walked = shown;
  for (const std::string& part : plain_components(relative, shown)) {
    walked += "/" + part;
    at = DirFd(child_directory(at.get(), part, walked));
  }
  return at;
}

void create_directory_durably(const fs::path& dir) {
  std::error_code ec;
  const fs::path absolute = fs::absolute(dir, ec).lexically_normal();
  if (ec) throw_errno(ec.value(), dir.string() + ": cannot resolve path");
  // The topmost directory that does not exist yet: its parent gets the new entry.
  fs::path top;
  for (fs::path p = absolute; !p.empty() && !fs::exists(p, ec); p = p.parent_path()) {
    top = p;
    if (p == p.parent_path()) break;
  }
  if (top.empty()) {
    if (!fs::is_directory(absolute, ec)) throw_errno(ENOTDIR, dir.string() + ": not a directory");
    return;
  }
  fs::create_directories(absolute, ec);
  if (ec) throw_errno(ec.value(), dir.string() + ": cannot create directory");
  for (fs::path p = absolute; p != top.parent_path(); p = p.parent_path()) fsync_directory(p);
  fsync_directory(top.parent_path());
}

}  // namespace idm::recording
