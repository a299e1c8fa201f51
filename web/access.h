// Who may ask idm-web what: the Host names it answers (DNS rebinding), the control token, and
// files read without following a symbolic link (the gap report, the token file). README.md here.
#pragma once

#include <sys/stat.h>

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace idm::web {

// localhost, 127.x.y.z (four decimal parts of 0..255) or [::1] (a Host header's name, without
// its port). Lower case expected.
bool loopback_name(std::string_view name);

// A Host header's value "name[:port]" or "[v6]:port" split: the name in lower case (brackets
// kept for v6, one trailing dot dropped); false when it does not parse (a bad port, stray bytes).
bool host_name(std::string_view value, std::string& name);

// The Host names a request may carry: the loopback names (on any port: an ssh tunnel's port is
// not this server's) and those listed (--allow-host, and the literal listen address), also on any
// port.
class HostPolicy {
 public:
  // "lab-pc", "192.168.1.5", "[fe80::1]" or "fe80::1" (a port after it is dropped); false when
  // it is not a host name.
  bool allow(std::string_view name);
  bool allows(std::string_view host_header) const;
  const std::vector<std::string>& listed() const { return names_; }

 private:
  std::vector<std::string> names_;
};

// Equal strings, in a time that does not depend on where they differ.
bool same_secret(std::string_view a, std::string_view b);

// A file read through a descriptor opened without following a symbolic link (O_NOFOLLOW),
// checked with fstat on that descriptor: a regular file of at most max_bytes.
struct FileRead {
  enum Kind { kOk, kMissing, kSymlink, kNotRegular, kTooLarge, kUnreadable };
  Kind kind = kUnreadable;
  std::string text;  // the content (kOk)
  std::string why;   // what is wrong, in words, naming the file
  struct stat st {};
};
FileRead read_file_nofollow(const std::string& path, std::size_t max_bytes);

// The control token from a file (--token-file): a regular file (not a symbolic link) owned by
// this process's user and readable by no one else (mode 0600 or 0400), holding one line of 16 to
// 1024 visible ASCII characters. model::InputError naming the file and what is wrong.
std::string token_from_file(const std::string& path);
// The token from IDM_WEB_TOKEN's value, checked as a file's: InputError naming the variable.
std::string token_from_text(const std::string& text, const std::string& what);

}  // namespace idm::web
