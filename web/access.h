// Who may ask idm-web what: the Host names it answers (DNS rebinding), the methods, control and
// its token (deny: the decision on every request), and files read without following a symbolic
// link (the gap report, the token file). README.md here.
#pragma once

#include <sys/stat.h>

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "web/http_request.h"

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

// What idm-web lets through: the Host names, control (--control) and its token (empty: none).
struct AccessRules {
  HostPolicy hosts;
  bool control = false;
  std::string token;
};

// Why a request is not let through: the status, what to say (one line, without its line end),
// whether it is a control request's (answered as JSON), and the headers that go with it (Allow,
// WWW-Authenticate).
struct Denial {
  int status = 0;
  std::string why;
  bool control = false;
  HeaderList headers;
};

// A control request: POST to /api/stop, /api/move, /api/jog or /api/velocity.
bool is_control(const HttpRequest& req);

// The decision on every request before its route: the Host it names (DNS rebinding: on every
// listen address), the method (GET and HEAD; POST on the control paths with --control), and for
// control the header a cross-site form cannot send (X-Idm-Control: 1) and, with a token,
// "Authorization: Bearer <token>". Nothing when the request may go on. The request has exactly
// one Host header (RequestReader refuses any other).
std::optional<Denial> deny(const AccessRules& rules, const HttpRequest& req);

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
