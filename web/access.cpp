#include "web/access.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>
#include <optional>

#include "model/stage.h"

namespace idm::web {

namespace {

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out)
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
  return out;
}

bool digits(std::string_view s, std::size_t max) {
  return !s.empty() && s.size() <= max &&
         std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

bool letter_or_digit(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9');
}

bool hex_digit(char c) {
  return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f') || (c >= 'A' && c <= 'F');
}

}  // namespace

bool loopback_name(std::string_view name) {
  if (name == "localhost" || name == "[::1]") return true;
  // 127.a.b.c, each part 0..255 in decimal
  if (name.rfind("127.", 0) != 0) return false;
  int parts = 0;
  while (true) {
    const std::size_t dot = name.find('.');
    const std::string_view part = name.substr(0, dot);
    if (!digits(part, 3) || std::stoi(std::string(part)) > 255) return false;
    ++parts;
    if (dot == std::string_view::npos) break;
    name.remove_prefix(dot + 1);
  }
  return parts == 4;
}

bool host_name(std::string_view value, std::string& name) {
  std::string_view host = value;
  std::optional<std::string_view> port;
  bool ok = false;
  if (!value.empty() && value.front() == '[') {  // [v6]: hex digits, ':' and a dotted IPv4 tail
    const std::size_t close = value.find(']');
    if (close == std::string_view::npos) return false;
    host = value.substr(0, close + 1);
    const std::string_view rest = value.substr(close + 1);
    if (!rest.empty() && rest.front() != ':') return false;
    if (!rest.empty()) port = rest.substr(1);
    const std::string_view inside = host.substr(1, host.size() - 2);
    ok = inside.find(':') != std::string_view::npos &&
         std::all_of(inside.begin(), inside.end(),
                     [](char c) { return hex_digit(c) || c == ':' || c == '.'; });
  } else {  // a name or an IPv4 address: letters, digits, '.', '-', '_'
    const std::size_t colon = value.find(':');
    host = value.substr(0, colon);
    if (colon != std::string_view::npos) port = value.substr(colon + 1);
    ok = !host.empty() && std::all_of(host.begin(), host.end(), [](char c) {
      return letter_or_digit(c) || c == '.' || c == '-' || c == '_';
    });
  }
  if (!ok || host.size() > 255) return false;
  if (port && (!digits(*port, 5) || std::stoi(std::string(*port)) > 65535)) return false;
  name = lower(host);
  if (name.size() > 1 && name.back() == '.') name.pop_back();
  return true;
}

bool HostPolicy::allow(std::string_view name) {
  if (name.empty()) return false;
  std::string n;
  // A bare IPv6 address ("fe80::1", "::") is bracketed as a Host header carries it.
  const bool bare_v6 = std::count(name.begin(), name.end(), ':') > 1 && name.front() != '[';
  if (!host_name(bare_v6 ? "[" + std::string(name) + "]" : std::string(name), n)) return false;
  if (std::find(names_.begin(), names_.end(), n) == names_.end()) names_.push_back(n);
  return true;
}

bool HostPolicy::allows(std::string_view host_header) const {
  std::string name;
  if (!host_name(host_header, name)) return false;
  return loopback_name(name) || std::find(names_.begin(), names_.end(), name) != names_.end();
}

bool same_secret(std::string_view a, std::string_view b) {
  // Every byte of the longer one is looked at whatever the content; the lengths count too.
  const std::size_t n = std::max(a.size(), b.size());
  unsigned diff = a.size() == b.size() ? 0U : 1U;
  for (std::size_t i = 0; i < n; ++i) {
    const auto x = static_cast<unsigned char>(i < a.size() ? a[i] : 0);
    const auto y = static_cast<unsigned char>(i < b.size() ? b[i] : 0);
    diff |= static_cast<unsigned>(x ^ y);
  }
  return diff == 0;
}

bool is_control(const HttpRequest& req) {
  return req.method == "POST" && (req.path == "/api/stop" || req.path == "/api/move" ||
                                  req.path == "/api/jog" || req.path == "/api/velocity");
}

std::optional<Denial> deny(const AccessRules& rules, const HttpRequest& req) {
  const std::string* host = req.header("host");
  if (!host || !rules.hosts.allows(*host))
    return Denial{403,
                  "forbidden: Host " + (host ? host->substr(0, 100) : std::string()) +
                      " is not a name of this server (idm-web --allow-host NAME)",
                  false,
                  {}};
  const bool read = req.method == "GET" || req.method == "HEAD";
  const bool control_post = rules.control && is_control(req);
  if (!read && !control_post)
    return Denial{405,
                  rules.control
                      ? "method not allowed"
                      : "method not allowed: idm-web is read-only (start it with --control)",
                  false,
                  {{"Allow", rules.control ? "GET, HEAD, POST" : "GET, HEAD"}}};
  if (!control_post) return std::nullopt;
  // A form on another site cannot set this header; a script there cannot without a CORS
  // preflight, which is never granted.
  const std::string* mark = req.header("x-idm-control");
  if (!mark || *mark != "1")
    return Denial{403, "control requests need the header X-Idm-Control: 1", true, {}};
  if (rules.token.empty()) return std::nullopt;
  const std::string* auth = req.header("authorization");
  const bool bearer = auth && auth->size() > 7 && auth->compare(0, 7, "Bearer ") == 0;
  if (bearer && same_secret(std::string_view(*auth).substr(7), rules.token)) return std::nullopt;
  return Denial{401,
                "control requests need the token: Authorization: Bearer TOKEN (idm-web "
                "--token-file or IDM_WEB_TOKEN)",
                true,
                {{"WWW-Authenticate", "Bearer realm=\"idm-web control\""}}};
}

FileRead read_file_nofollow(const std::string& path, std::size_t max_bytes) {
  FileRead r;
  // O_NONBLOCK: a FIFO put there does not hang the reader (it is refused below).
  const int fd = open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) {
    const int e = errno;
    r.kind = e == ENOENT  ? FileRead::kMissing
             : e == ELOOP ? FileRead::kSymlink
                          : FileRead::kUnreadable;
    r.why = e == ELOOP ? path + " is a symbolic link: not followed (give the file itself)"
                       : path + ": " + std::strerror(e);
    return r;
  }
  const std::unique_ptr<const int, void (*)(const int*)> closer(&fd,
                                                                [](const int* f) { close(*f); });
  if (fstat(fd, &r.st) != 0) {
    r.why = path + ": fstat: " + std::strerror(errno);
    return r;
  }
  if (!S_ISREG(r.st.st_mode)) {
    r.kind = FileRead::kNotRegular;
    r.why = path + " is not a regular file";
    return r;
  }
  if (static_cast<std::size_t>(r.st.st_size) > max_bytes) {
    r.kind = FileRead::kTooLarge;
    r.why = path + " is " + std::to_string(r.st.st_size) + " bytes, at most " +
            std::to_string(max_bytes) + " are read";
    return r;
  }
  // Read to the end, never past max_bytes (the file may have grown since fstat): a buffer of the
  // size fstat gave and a byte more (the end seen without a second read), doubled as needed.
  r.text.resize(static_cast<std::size_t>(r.st.st_size) + 1);
  std::size_t got = 0;
  while (got <= max_bytes) {
    if (got == r.text.size()) r.text.resize(std::min(max_bytes + 1, 2 * got));
    const ssize_t n = read(fd, r.text.data() + got, r.text.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      r.why = path + ": read: " + std::strerror(errno);
      return r;
    }
    if (n == 0) break;
    got += static_cast<std::size_t>(n);
  }
  if (got > max_bytes) {
    r.kind = FileRead::kTooLarge;
    r.why = path + " is larger than " + std::to_string(max_bytes) + " bytes";
    r.text.clear();
    return r;
  }
  r.text.resize(got);
  r.kind = FileRead::kOk;
  return r;
}

std::string token_from_text(const std::string& text, const std::string& what) {
  std::string t = text;
  while (!t.empty() && (t.back() == '\n' || t.back() == '\r' || t.back() == ' ')) t.pop_back();
  const bool visible = std::all_of(t.begin(), t.end(), [](char c) { return c > 0x20 && c < 0x7f; });
  if (t.size() < 16 || t.size() > 1024 || !visible)
    throw model::InputError(what +
                            ": the token must be one line of 16 to 1024 visible ASCII characters "
                            "(no blanks)");
  return t;
}

std::string token_from_file(const std::string& path) {
  const FileRead f = read_file_nofollow(path, 4096);
  if (f.kind != FileRead::kOk) throw model::InputError("--token-file: " + f.why);
  if (f.st.st_uid != geteuid())
    throw model::InputError("--token-file: " + path + " belongs to uid " +
                            std::to_string(f.st.st_uid) + ", not to idm-web's user (uid " +
                            std::to_string(geteuid()) + ")");
  if ((f.st.st_mode & 077) != 0) {
    char mode[8];
    std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(f.st.st_mode & 07777));
    throw model::InputError("--token-file: " + path + " may be read by others (mode " + mode +
                            "): chmod 600 " + path);
  }
  return token_from_text(f.text, "--token-file " + path);
}

}  // namespace idm::web
