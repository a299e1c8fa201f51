#include "web/http_request.h"

#include <algorithm>

namespace idm::web {

namespace {

constexpr std::size_t kNone = std::string_view::npos;

char lower(char c) {
  return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c;
}

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = lower(c);
  return out;
}

bool token_char(char c) {
  const auto u = static_cast<unsigned char>(c);
  if (u <= 0x20 || u >= 0x7f) return false;
  return std::string_view("\"(),/:;<=>?@[\\]{}").find(c) == kNone;
}

bool is_token(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), token_char);
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  c = lower(c);
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

// The first `name=value` of an a=b&c=d list, decoded.
std::optional<std::string> find_param(std::string_view list, std::string_view name) {
  while (!list.empty()) {
    const std::size_t amp = list.find('&');
    const std::string_view item = list.substr(0, amp);
    const std::size_t eq = item.find('=');
    if (percent_decode(item.substr(0, eq)) == name)
      return eq == kNone ? std::string() : percent_decode(item.substr(eq + 1));
    if (amp == kNone) break;
    list.remove_prefix(amp + 1);
  }
  return std::nullopt;
}

// `token` (lower case) is one of the comma-separated items of the header value `list`.
bool has_token(const std::string* list, std::string_view token) {
  if (!list) return false;
  std::string_view rest = *list;
  while (!rest.empty()) {
    const std::size_t comma = rest.find(',');
    if (lower(trim(rest.substr(0, comma))) == token) return true;
    if (comma == kNone) break;
    rest.remove_prefix(comma + 1);
  }
  return false;
}

// The request line: METHOD SP origin-form SP HTTP/1.x; a refusal, or nothing.
std::optional<Refusal> parse_request_line(std::string_view line, HttpRequest& r) {
  const std::size_t a = line.find(' ');
  const std::size_t b = a == kNone ? kNone : line.find(' ', a + 1);
  if (b == kNone || line.find(' ', b + 1) != kNone)
    return Refusal{400, "a request line is METHOD /path HTTP/1.1"};
  r.method = std::string(line.substr(0, a));
  r.target = std::string(line.substr(a + 1, b - a - 1));
  r.version = std::string(line.substr(b + 1));
  if (!is_token(r.method) || r.method.size() > 32) return Refusal{400, "a malformed method"};
  if (r.target.empty() || r.target[0] != '/' ||
      !std::all_of(r.target.begin(), r.target.end(), [](char c) {
        const auto u = static_cast<unsigned char>(c);
        return u > 0x20 && u < 0x7f;
      }))
    return Refusal{400, "the target must be a path starting with / (printable ASCII)"};
  if (r.version != "HTTP/1.1" && r.version != "HTTP/1.0") {
    const bool http = r.version.size() == 8 && r.version.compare(0, 5, "HTTP/") == 0;
    return http ? Refusal{505, "HTTP/1.1 and HTTP/1.0 only"} : Refusal{400, "not HTTP"};
  }
  const std::size_t q = r.target.find('?');
  r.path = r.target.substr(0, q);
  r.query = q == kNone ? "" : r.target.substr(q + 1);
  return std::nullopt;
}

// One header field line (without its line end) into r.headers; a refusal, or nothing.
std::optional<Refusal> parse_field(std::string_view line, HttpRequest& r) {
  if (line.front() == ' ' || line.front() == '\t')
    return Refusal{400, "a folded header line (obsolete line folding is not accepted)"};
  const std::size_t colon = line.find(':');
  if (colon == kNone || !is_token(line.substr(0, colon)))
    return Refusal{400, "a header line is Name: value"};
  const std::string_view value = trim(line.substr(colon + 1));
  for (const char c : value) {
    const auto u = static_cast<unsigned char>(c);
    if ((u < 0x20 && c != '\t') || u == 0x7f)
      return Refusal{400, "a control character in a header value"};
  }
  r.headers.emplace_back(lower(line.substr(0, colon)), std::string(value));
  return std::nullopt;
}

}  // namespace

std::string percent_decode(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '+') {
      out += ' ';
    } else if (c == '%' && i + 2 < text.size() && hex_value(text[i + 1]) >= 0 &&
               hex_value(text[i + 2]) >= 0) {
      out += static_cast<char>(hex_value(text[i + 1]) * 16 + hex_value(text[i + 2]));
      i += 2;
    } else {
      out += c;
    }
  }
  return out;
}

const std::string* HttpRequest::header(std::string_view name) const {
  for (const auto& [n, v] : headers)
    if (n == name) return &v;
  return nullptr;
}

std::size_t HttpRequest::header_count(std::string_view name) const {
  return static_cast<std::size_t>(std::count_if(headers.begin(), headers.end(),
                                                [name](const auto& h) { return h.first == name; }));
}

std::optional<std::string> HttpRequest::param(std::string_view name) const {
  if (auto v = find_param(query, name)) return v;
  const std::string* type = header("content-type");
  if (type && lower(*type).rfind("application/x-www-form-urlencoded", 0) == 0)
    return find_param(body, name);
  return std::nullopt;
}

bool HttpRequest::keep_alive() const {
  const std::string* c = header("connection");
  return version == "HTTP/1.1" ? !has_token(c, "close") : has_token(c, "keep-alive");
}

RequestReader::Step RequestReader::refuse(int status, std::string why) {
  refusal_ = Refusal{status, std::move(why)};
  return step_ = Step::kRefused;
}

RequestReader::Step RequestReader::read(std::string_view in) {
  if (step_ != Step::kMore) return step_;
  if (head_end_ == kNone) {
    if (scan_head(in) == Step::kRefused) return step_;
    if (head_end_ != kNone && parse_head(in) == Step::kRefused) return step_;
  }
  if (head_end_ != kNone && in.size() >= head_end_ + body_) {
    request_.body = std::string(in.substr(head_end_, body_));
    return step_ = Step::kWhole;
  }
  // Never reached by a request within the limits: one is refused before it is all there.
  if (in.size() >= limits_.max_request_bytes())
    return refuse(413, "the request is larger than its limits");
  return Step::kMore;
}

// Scans the new bytes for the end of the head, counting lines: a limit passed is a refusal
// (414, 431). Sets head_end_ once the blank line came.
RequestReader::Step RequestReader::scan_head(std::string_view in) {
  const auto too_large = [&] {
    return refuse(431, "the request's header fields are too large: at most " +
                           std::to_string(limits_.max_header_fields) + " fields and " +
                           std::to_string(limits_.max_header_bytes) + " bytes");
  };
  for (; scanned_ < in.size() && head_end_ == kNone; ++scanned_) {
    if (in[scanned_] != '\n') continue;
    const std::size_t len = scanned_ - line_start_;
    const bool blank = len == 0 || (len == 1 && in[line_start_] == '\r');
    if (line_end_ == kNone) {
      if (!blank) {  // blank lines before the request line are skipped
        request_line_ = line_start_;
        line_end_ = scanned_;
      }
      if (scanned_ > limits_.max_request_line_bytes) break;
    } else if (blank) {
      head_end_ = scanned_ + 1;
    } else if (++fields_ > limits_.max_header_fields) {
      return too_large();
    }
    line_start_ = scanned_ + 1;
  }
  if (line_end_ == kNone || line_end_ > limits_.max_request_line_bytes) {
    if (std::min(line_end_, in.size()) > limits_.max_request_line_bytes)
      return refuse(414, "the request line is longer than " +
                             std::to_string(limits_.max_request_line_bytes) + " bytes");
    return Step::kMore;
  }
  const std::size_t end = head_end_ == kNone ? in.size() : head_end_;
  if (end - line_end_ - 1 > limits_.max_header_bytes) return too_large();
  return Step::kMore;
}

// The whole head (request line and fields) into request_, and the body's length.
RequestReader::Step RequestReader::parse_head(std::string_view in) {
  std::string_view line = in.substr(request_line_, line_end_ - request_line_);
  if (line.back() == '\r') line.remove_suffix(1);  // not blank: something is left
  if (auto r = parse_request_line(line, request_)) return refuse(r->status, std::move(r->why));
  if (parse_fields(in) == Step::kRefused) return step_;
  if (request_.header_count("host") != 1)
    return refuse(400, "a request needs exactly one Host header");
  return body_length();
}

// The header lines between the request line and the blank line that ends the head.
RequestReader::Step RequestReader::parse_fields(std::string_view in) {
  std::size_t pos = line_end_ + 1;
  while (pos < head_end_) {
    const std::size_t nl = in.find('\n', pos);
    std::string_view line = in.substr(pos, nl - pos);
    pos = nl + 1;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (line.empty()) break;
    if (auto r = parse_field(line, request_)) return refuse(r->status, std::move(r->why));
  }
  return Step::kMore;
}

// What the head says of the body: its length (Content-Length), within the limit. A body in chunks
// is refused, and so is a Content-Length given twice differently: nothing is left for a second
// reader to frame otherwise (request smuggling).
RequestReader::Step RequestReader::body_length() {
  body_ = 0;
  if (request_.header("transfer-encoding"))
    return refuse(411, "a body in chunks (Transfer-Encoding) is not accepted: send Content-Length");
  const std::string* first = request_.header("content-length");
  if (!first) return Step::kMore;
  for (const auto& [name, value] : request_.headers)
    if (name == "content-length" && value != *first)
      return refuse(400, "Content-Length given twice, differently");
  if (first->empty() || first->size() > 18 ||
      first->find_first_not_of("0123456789") != std::string::npos)
    return refuse(400, "Content-Length: a decimal number of bytes");
  const std::size_t n = std::stoull(*first);
  if (n > limits_.max_body_bytes)
    return refuse(413, "the body is " + *first + " bytes, at most " +
                           std::to_string(limits_.max_body_bytes) + " are accepted");
  body_ = n;
  return Step::kMore;
}

ParsedRequest parse_request(std::string_view bytes, const HttpLimits& limits) {
  RequestReader reader(limits);
  ParsedRequest out;
  out.step = reader.read(bytes);
  if (out.step == RequestReader::Step::kWhole) {
    out.request = std::move(reader.request());
    out.size = reader.size();
  } else if (out.step == RequestReader::Step::kRefused) {
    out.refusal = reader.refusal();
  }
  return out;
}

}  // namespace idm::web
