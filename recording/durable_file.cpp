#include "recording/durable_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <string>
#include <system_error>

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

fs::path temporary_name(const fs::path& final_path) {
  return final_path.parent_path() / ("." + final_path.filename().string() + ".tmp");
}

}  // namespace

void write_file_durably(const fs::path& final_path, std::string_view content) {
  const fs::path tmp = temporary_name(final_path);
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw_errno(errno, final_path.string() + ": cannot create " + tmp.string());
  auto fail = [&](int error, const std::string& what, bool close_fd) {
    if (close_fd) ::close(fd);
    ::unlink(tmp.c_str());
    throw_errno(error, final_path.string() + ": " + what);
  };
  const char* data = content.data();
  std::size_t left = content.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, data, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      fail(errno, "cannot write " + tmp.string(), true);
    }
    data += n;
    left -= static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) fail(errno, "cannot sync " + tmp.string(), true);
  if (::close(fd) != 0) fail(errno, "cannot close " + tmp.string(), false);
  if (::rename(tmp.c_str(), final_path.c_str()) != 0)
    fail(errno, "cannot rename " + tmp.string() + " to " + final_path.filename().string(), false);
  fsync_directory(final_path.parent_path().empty() ? fs::path(".") : final_path.parent_path());
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
