// Parsers of idmd's replies (daemon/README.md, "Command protocol"): what a client reads from the
// socket is outside input, so every parser here checks what it reads and throws ReplyError on
// anything it does not expect (never reads past its input, never crashes: tests/fuzz).
#pragma once

#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace idm::client {

// The longest reply line a client accepts (SYST:ERR:ALL? of a full queue is well below).
inline constexpr std::size_t kMaxReplyBytes = std::size_t{64} * 1024;

struct ReplyError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// A number as idmd prints it; SCPI's 9.91E37 (not a number) is NaN, +-9.9E37 +-infinity.
double parse_reply_number(std::string_view text);
// A non-negative integer (a counter).
std::uint64_t parse_reply_count(std::string_view text);

// `<code>,"<text>"` (SYSTem:ERRor?); a doubled "" in the text is one ".
struct ErrorReply {
  int code = 0;
  std::string text;
};
ErrorReply parse_error(std::string_view reply);

// Blank-separated key=value words (STATus?, SYSTem:LOOP?); a repeated key is an error.
std::map<std::string, std::string> parse_key_values(std::string_view reply);

// STATus? of one axis.
struct AxisStatus {
  std::string name;   // axis=
  std::string state;  // IDLE, MOVING, SETTLING, FAULT, ...
  bool done = true;   // done=
  bool position_valid = false;
  double position_m = 0;  // NaN when not valid
  double target_m = 0;
  std::string fault;                // none, stall, ...
  double lower_m = 0, upper_m = 0;  // soft limits (+-inf when unset)
  std::uint64_t moves = 0, bursts = 0, cycles = 0;
  bool referenced = false;
  std::string device;        // up, lost
  std::string eot;           // "" or low / high (end of travel), when the daemon reports it
  std::string daemon_error;  // none or the daemon core's last error (blanks as _)
  double offset_m = 0;       // offset=: the user offset (0 from a daemon that has none)
};
AxisStatus parse_status(std::string_view reply);

// SYSTem:LOOP?: the real-time loop's wake-ups and its latency histogram.
struct LoopStats {
  double period_s = 0;
  std::uint64_t wakeups = 0, misses = 0;
  double min_s = 0, avg_s = 0, max_s = 0;
  double bin_width_s = 0;
  std::vector<std::uint64_t> hist;  // [k, k+1) * bin_width_s; the last bin holds the rest
};
LoopStats parse_loop(std::string_view reply);

// SYSTem:CLIents:TABLe?: idmd's client table (every connection, the asking one included).
// Invariant (checked): slots + stop_only + draining == connected.
struct ClientTable {
  std::uint64_t connected = 0;
  std::uint64_t slots = 0;  // holding one of max_clients' slots
  std::uint64_t max_clients = 0;
  std::uint64_t stop_only = 0;  // in a stop-only slot (the table was full)
  std::uint64_t overflow_slots = 0;
  std::uint64_t draining = 0;  // half-closed, still owed a *OPC? reply
};
ClientTable parse_client_table(std::string_view reply);

// SWEEP?: `<state>,<axis>,<written>,<failed>,<planned>,"<dir>"` (axis 0-based, -1: none yet).
struct SweepInfo {
  std::string state;  // NONE, RUNNING, DONE, STOPPED, FAILED
  int axis = -1;
  std::uint64_t written = 0, failed = 0, planned = 0;
  std::string directory;
};
SweepInfo parse_sweep(std::string_view reply);

// POSition:ALL?: comma-separated numbers (NaN for an untrusted one).
std::vector<double> parse_number_list(std::string_view reply);

// REGion?: `CUTOFF|ONESTEP|MULTISTEP,<step_m>`.
struct RegionReply {
  std::string region;
  double step_m = 0;
};
RegionReply parse_region(std::string_view reply);

// STATus:OPERation?'s bits (docs/command-protocol.md): bit k's name, nullptr past the last.
const char* operation_bit_name(int bit);
inline constexpr int kOperationBits = 10;
// The names of the bits set, e.g. {"in position", "position valid"}.
std::vector<std::string> operation_bit_words(std::uint32_t bits);

}  // namespace idm::client
