#include "client/replies.h"

#include <cmath>
#include <limits>

#include "daemon/protocol.h"

namespace idm::client {

namespace {

std::string shown(std::string_view text) {
  std::string out;
  for (const char c : text.substr(0, 80)) out += (c >= 0x20 && c < 0x7f) ? c : '?';
  return text.size() > 80 ? out + "..." : out;
}

std::vector<std::string_view> split(std::string_view text, char sep) {
  std::vector<std::string_view> parts;
  std::size_t start = 0;
  for (;;) {
    const std::size_t at = text.find(sep, start);
    parts.push_back(text.substr(start, at == std::string_view::npos ? text.npos : at - start));
    if (at == std::string_view::npos) return parts;
    start = at + 1;
  }
}

const std::string& need(const std::map<std::string, std::string>& kv, const char* key,
                        std::string_view reply) {
  const auto it = kv.find(key);
  if (it == kv.end()) throw ReplyError(std::string("no ") + key + "= in '" + shown(reply) + "'");
  return it->second;
}

bool flag(const std::string& value, const char* key) {
  if (value == "0") return false;
  if (value == "1") return true;
  throw ReplyError(std::string(key) + "=" + shown(value) + ": expected 0 or 1");
}

}  // namespace

double parse_reply_number(std::string_view text) {
  double value = 0;
  if (!idm::daemon::parse_number(text, "reply", value).ok())
    throw ReplyError("'" + shown(text) + "' is not a number");
  if (std::fabs(value - 9.91e37) <= 1e33) return std::numeric_limits<double>::quiet_NaN();
  if (value >= 9.9e37) return std::numeric_limits<double>::infinity();
  if (value <= -9.9e37) return -std::numeric_limits<double>::infinity();
  return value;
}

std::uint64_t parse_reply_count(std::string_view text) {
  if (text.empty() || text.size() > 19 || text.find_first_not_of("0123456789") != text.npos)
    throw ReplyError("'" + shown(text) + "' is not a count");
  std::uint64_t n = 0;
  for (const char c : text) n = n * 10 + static_cast<std::uint64_t>(c - '0');
  return n;
}

ErrorReply parse_error(std::string_view reply) {
  const std::size_t comma = reply.find(',');
  if (comma == std::string_view::npos || comma == 0 || comma > 7)
    throw ReplyError("'" + shown(reply) + "' is not <code>,\"<text>\"");
  std::string_view code = reply.substr(0, comma);
  const bool negative = code.front() == '-';
  if (negative) code.remove_prefix(1);
  // As idmd prints them: no leading zero, no "-0" (so "00,..." never reads as "no error").
  if (code.size() > 1 && code.front() == '0')
    throw ReplyError("'" + shown(reply) + "': a code with a leading zero");
  if (negative && code == "0") throw ReplyError("'" + shown(reply) + "': the code -0");
  ErrorReply e;
  e.code = static_cast<int>(parse_reply_count(code)) * (negative ? -1 : 1);
  std::string_view text = reply.substr(comma + 1);
  if (text.size() < 2 || text.front() != '"' || text.back() != '"')
    throw ReplyError("'" + shown(reply) + "': the error's text is not quoted");
  text = text.substr(1, text.size() - 2);
  for (std::size_t k = 0; k < text.size(); ++k) {
    if (text[k] == '"') {
      if (k + 1 >= text.size() || text[k + 1] != '"')
        throw ReplyError("'" + shown(reply) + "': a lone '\"' in the error's text");
      ++k;
    }
    e.text += text[k];
  }
  return e;
}

std::map<std::string, std::string> parse_key_values(std::string_view reply) {
  std::map<std::string, std::string> kv;
  for (const std::string_view word : split(reply, ' ')) {
    if (word.empty()) continue;
    const std::size_t eq = word.find('=');
    if (eq == std::string_view::npos || eq == 0)
      throw ReplyError("'" + shown(word) + "' is not key=value");
    if (!kv.emplace(std::string(word.substr(0, eq)), std::string(word.substr(eq + 1))).second)
      throw ReplyError("'" + shown(word.substr(0, eq)) + "' twice in '" + shown(reply) + "'");
  }
  return kv;
}

AxisStatus parse_status(std::string_view reply) {
  const auto kv = parse_key_values(reply);
  AxisStatus s;
  s.name = need(kv, "axis", reply);
  s.state = need(kv, "state", reply);
  s.done = flag(need(kv, "done", reply), "done");
  s.position_valid = flag(need(kv, "position_valid", reply), "position_valid");
  s.position_m = s.position_valid ? parse_reply_number(need(kv, "position", reply))
                                  : std::numeric_limits<double>::quiet_NaN();
  if (s.position_valid && !std::isfinite(s.position_m))
    throw ReplyError("position_valid=1 with position=" + shown(need(kv, "position", reply)));
  s.target_m = parse_reply_number(need(kv, "target", reply));
  s.fault = need(kv, "fault", reply);
  s.lower_m = parse_reply_number(need(kv, "lower", reply));
  s.upper_m = parse_reply_number(need(kv, "upper", reply));
  s.moves = parse_reply_count(need(kv, "moves", reply));
  s.bursts = parse_reply_count(need(kv, "bursts", reply));
  s.cycles = parse_reply_count(need(kv, "cycles", reply));
  s.referenced = flag(need(kv, "referenced", reply), "referenced");
  s.device = need(kv, "device", reply);
  if (const auto it = kv.find("eot"); it != kv.end() && it->second != "none") s.eot = it->second;
  if (const auto it = kv.find("daemon_error"); it != kv.end()) s.daemon_error = it->second;
  if (const auto it = kv.find("offset"); it != kv.end())
    s.offset_m = parse_reply_number(it->second);
  return s;
}

LoopStats parse_loop(std::string_view reply) {
  const auto kv = parse_key_values(reply);
  LoopStats l;
  l.period_s = parse_reply_number(need(kv, "period", reply));
  l.wakeups = parse_reply_count(need(kv, "wakeups", reply));
  l.misses = parse_reply_count(need(kv, "misses", reply));
  l.min_s = parse_reply_number(need(kv, "min", reply));
  l.avg_s = parse_reply_number(need(kv, "avg", reply));
  l.max_s = parse_reply_number(need(kv, "max", reply));
  l.bin_width_s = parse_reply_number(need(kv, "bin_width", reply));
  if (!(l.bin_width_s > 0) || !std::isfinite(l.bin_width_s))
    throw ReplyError("bin_width=" + shown(need(kv, "bin_width", reply)) + ": expected > 0");
  const auto bins = split(need(kv, "hist", reply), ';');
  if (bins.size() > 1024) throw ReplyError("hist= has more than 1024 bins");
  for (const std::string_view b : bins) l.hist.push_back(parse_reply_count(b));
  return l;
}

ClientTable parse_client_table(std::string_view reply) {
  const auto kv = parse_key_values(reply);
  ClientTable t;
  t.connected = parse_reply_count(need(kv, "connected", reply));
  t.slots = parse_reply_count(need(kv, "slots", reply));
  t.max_clients = parse_reply_count(need(kv, "max_clients", reply));
  t.stop_only = parse_reply_count(need(kv, "stop_only", reply));
  t.overflow_slots = parse_reply_count(need(kv, "overflow_slots", reply));
  t.draining = parse_reply_count(need(kv, "draining", reply));
  for (const std::uint64_t n : {t.connected, t.max_clients, t.overflow_slots})
    if (n > 1000000) throw ReplyError("'" + shown(reply) + "': more than 1e6 clients");
  // connected bounds the three below (as long as they add up), so the sum cannot wrap.
  if (t.slots > t.connected || t.stop_only > t.connected || t.draining > t.connected ||
      t.slots + t.stop_only + t.draining != t.connected)
    throw ReplyError("'" + shown(reply) + "': slots + stop_only + draining is not connected");
  return t;
}

SweepInfo parse_sweep(std::string_view reply) {
  // The directory is last and quoted; the five fields before it hold no comma or quote.
  const std::size_t quote = reply.find('"');
  if (quote == std::string_view::npos || quote == 0 || reply[quote - 1] != ',')
    throw ReplyError("'" + shown(reply) + "' is not a SWEEP? reply");
  const auto fields = split(reply.substr(0, quote - 1), ',');
  if (fields.size() != 5) throw ReplyError("'" + shown(reply) + "' is not a SWEEP? reply");
  SweepInfo s;
  s.state = std::string(fields[0]);
  if (s.state.empty()) throw ReplyError("'" + shown(reply) + "': an empty sweep state");
  std::string_view axis = fields[1];
  if (axis == "-1") {
    s.axis = -1;
  } else {
    const std::uint64_t a = parse_reply_count(axis);
    if (a > 100000) throw ReplyError("SWEEP? axis " + shown(axis) + " is out of range");
    s.axis = static_cast<int>(a);
  }
  s.written = parse_reply_count(fields[2]);
  s.failed = parse_reply_count(fields[3]);
  s.planned = parse_reply_count(fields[4]);
  // The quoted directory, with "" as one ".
  const ErrorReply dir = parse_error("0," + std::string(reply.substr(quote)));
  s.directory = dir.text;
  return s;
}

std::vector<double> parse_number_list(std::string_view reply) {
  std::vector<double> out;
  for (const std::string_view item : split(reply, ',')) out.push_back(parse_reply_number(item));
  return out;
}

RegionReply parse_region(std::string_view reply) {
  const auto fields = split(reply, ',');
  if (fields.size() != 2) throw ReplyError("'" + shown(reply) + "' is not <region>,<step>");
  RegionReply r;
  r.region = std::string(fields[0]);
  if (r.region != "CUTOFF" && r.region != "ONESTEP" && r.region != "MULTISTEP")
    throw ReplyError("'" + shown(fields[0]) + "' is not CUTOFF, ONESTEP or MULTISTEP");
  r.step_m = parse_reply_number(fields[1]);
  return r;
}

const char* operation_bit_name(int bit) {
  static const char* const kNames[kOperationBits] = {
      "moving",         "in position",   "holding", "referenced",     "at lower limit",
      "at upper limit", "end of travel", "fault",   "position valid", "referencing"};
  return bit >= 0 && bit < kOperationBits ? kNames[bit] : nullptr;
}

std::vector<std::string> operation_bit_words(std::uint32_t bits) {
  std::vector<std::string> words;
  for (int k = 0; k < kOperationBits; ++k)
    if (bits & (1u << k)) words.emplace_back(operation_bit_name(k));
  return words;
}

}  // namespace idm::client
