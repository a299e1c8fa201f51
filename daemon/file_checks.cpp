#include "daemon/file_checks.h"

#include <fcntl.h>
#include <pwd.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "daemon/reference_file.h"
#include "model/yaml_util.h"

namespace idm::daemon {

using model::InputError;

namespace {

constexpr std::size_t kMinTokenChars = 16;
constexpr std::size_t kMaxTokenChars = 256;

bool token_char(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
         std::strchr("-._~+/=", c) != nullptr;
}

}  // namespace

std::string octal_mode(unsigned mode) {
  char b[8];
  std::snprintf(b, sizeof b, "%04o", mode & 07777);
  return b;
}

std::string read_token_file(const std::string& path) {
  const std::string what = "server.auth_token_file " + path + ": ";
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK | O_NOCTTY);
  if (fd < 0)
    throw InputError(what + (errno == ELOOP ? std::string("a symbolic link; refused")
                                            : "cannot open: " + std::string(std::strerror(errno))));
  struct stat st {};
  const bool stat_ok = ::fstat(fd, &st) == 0;
  ::close(fd);
  if (!stat_ok || !S_ISREG(st.st_mode)) throw InputError(what + "not a regular file; refused");
  if (st.st_mode & (S_IROTH | S_IWOTH | S_IWGRP))
    throw InputError(what + "mode " + octal_mode(st.st_mode) +
                     " lets other users read or change the token: chmod 0600 (or 0640 with "
                     "idmd's group)");
  const std::string text = model::read_regular_file(path, 4096);
  std::string token = text.substr(0, text.find('\n'));
  while (!token.empty() && (token.back() == ' ' || token.back() == '\r' || token.back() == '\t'))
    token.pop_back();
  token.erase(0, token.find_first_not_of(" \t"));
  if (token.size() < kMinTokenChars || token.size() > kMaxTokenChars)
    throw InputError(what + "the token (its first line) has " + std::to_string(token.size()) +
                     " characters, allowed " + std::to_string(kMinTokenChars) + " to " +
                     std::to_string(kMaxTokenChars) +
                     " (e.g. `head -c 24 /dev/urandom | base64 > FILE`)");
  for (char c : token)
    if (!token_char(c))
      throw InputError(what + "the token may hold letters, digits and -._~+/= only");
  return token;
}

namespace {

// The permissions of `path` (a file or a directory) as `what` in a finding.
void check_permissions(const std::string& what, const std::string& path, FileFindings& out) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return;
  const bool dir = S_ISDIR(st.st_mode);
  const bool sticky = (st.st_mode & S_ISVTX) != 0;
  const std::string mode = octal_mode(st.st_mode);
  if ((st.st_mode & S_IWOTH) && !(dir && sticky)) {
    out.errors.push_back(what + " " + path + " is writable by every user (mode " + mode +
                         "): another user could change what idmd reads or redirect what it "
                         "writes; chmod o-w");
    return;
  }
  if (st.st_mode & S_IWOTH)
    out.warnings.push_back(what + " " + path + " is a shared directory (mode " + mode +
                           "): another user may place files there; prefer idmd's own "
                           "(/var/lib/idmd)");
  else if ((st.st_mode & S_IWGRP) && st.st_gid != ::getegid())
    out.warnings.push_back(what + " " + path + " is writable by group " +
                           std::to_string(st.st_gid) + " (mode " + mode + ")");
  if (st.st_uid != 0 && st.st_uid != ::geteuid())
    out.warnings.push_back(what + " " + path + " belongs to user " + std::to_string(st.st_uid) +
                           ", not to root or to idmd's user: they can change its mode");
}

// "user idmd (uid 998)": the user whose permissions access() checks.
std::string this_user() {
  const uid_t uid = ::getuid();
  const passwd* pw = ::getpwuid(uid);
  return "user " + (pw != nullptr ? std::string(pw->pw_name) + " " : std::string()) + "(uid " +
         std::to_string(uid) + ")";
}

std::string parent_of(const std::string& file) {
  const std::string dir = std::filesystem::path(file).parent_path().string();
  return dir.empty() ? "." : dir;
}

// A file an axis writes: its directory there and writable; the file, if there, a regular file
// that reads (`reads` throws or returns "" / why not).
template <typename Reads>
void check_axis_file(const std::string& key, const std::string& file, Reads&& reads,
                     FileFindings& out) {
  if (file.empty()) return;
  const std::string dir = parent_of(file);
  check_permissions(key + "'s directory", dir, out);
  if (::access(dir.c_str(), W_OK | X_OK) != 0) {
    out.errors.push_back(
        key + ": the directory " + dir + " " +
        (errno == ENOENT ? "does not exist" : "is not writable by " + this_user()) +
        ": what the axis learns could not be saved");
    return;
  }
  struct stat st {};
  if (::lstat(file.c_str(), &st) != 0) return;  // not there yet: idmd writes it
  if (!S_ISREG(st.st_mode)) {
    out.errors.push_back(key + ": " + file +
                         " is not a regular file (a link, a FIFO, a directory): refused");
    return;
  }
  check_permissions(key, file, out);
  if (std::string why = reads(file); !why.empty())
    out.errors.push_back(key + ": " + why +
                         "; idmd does not overwrite a file it cannot read: fix it or move it "
                         "away");
}

// recording.data_dir: a directory this user can write in, or one it can make (a note: idmd makes
// it at start); else SWEEP fails (a warning: motion does not need it).
void check_data_dir(const std::string& data, FileFindings& out) {
  check_permissions("recording.data_dir", data, out);
  const std::string what = "recording.data_dir " + data + ": ";
  std::error_code ec;
  if (std::filesystem::exists(data, ec) && !std::filesystem::is_directory(data, ec)) {
    out.warnings.push_back(what + "not a directory: SWEEP will fail");
    return;
  }
  std::filesystem::path existing = std::filesystem::absolute(data);
  while (!existing.empty() && !std::filesystem::exists(existing, ec))
    existing = existing.parent_path();
  const bool missing = existing != std::filesystem::absolute(data);
  if (::access(existing.c_str(), W_OK | X_OK) != 0)
    out.warnings.push_back(what + (missing ? "does not exist, and " : "") + existing.string() +
                           " is not writable by " + this_user() + ": SWEEP will fail");
  else if (missing)
    out.notes.push_back(what + "does not exist yet: idmd makes it at start (below " +
                        existing.string() + ")");
}

}  // namespace

FileFindings check_config_files(const DaemonConfig& c) {
  FileFindings out;
  check_permissions("the configuration file", c.file, out);
  check_permissions("the configuration's directory", parent_of(c.file), out);
  check_data_dir(c.recording.data_dir, out);
  for (const AxisConfig& a : c.axes) {
    const std::string prefix = c.axes.size() > 1 ? "axes." + a.name + "." : "";
    // Read as idmd reads it at start: the file's content, and that it is this axis's stage's
    // (a calibration another config wrote, of another stage, stops idmd there).
    check_axis_file(
        prefix + "control.calibration_file", a.control.calibration_file,
        [&a](const std::string& f) -> std::string {
          try {
            control::Calibration calibration(a.stage.stage, a.control.calibration);
            std::string error;
            if (!calibration.load(f, error)) return error;
          } catch (const std::exception& e) {
            return e.what();
          }
          return {};
        },
        out);
    check_axis_file(
        prefix + "reference_file", a.reference_file,
        [](const std::string& f) -> std::string {
          try {
            (void)load_reference(f);
          } catch (const std::exception& e) {
            return e.what();
          }
          return {};
        },
        out);
  }
  return out;
}

}  // namespace idm::daemon
