#include "daemon/file_checks.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

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

}  // namespace idm::daemon
