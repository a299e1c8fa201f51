// The client side's parsers of idmd's replies and of addresses (client/replies.h,
// client/connection.h): what idmctl, idm-tango and idm-web read from the daemon's socket, the
// environment and the command line.
//
// Input: byte 0 picks the parser; the rest is the reply line (or address).
//
// Invariants:
//  * a parser returns or throws its own error type (ReplyError; AddressError for addresses),
//    never anything else, and never reads past its input (AddressSanitizer);
//  * STATus?: position_valid is exactly when the position is finite;
//  * SYSTem:LOOP?: a positive, finite bin width, at most 1024 bins;
//  * SYSTem:ERRor?: the code fits the reply, and code 0 is only "0,...";
//  * REGion?: one of the three region names;
//  * SYSTem:CLIents:TABLe?: slots + stop_only + draining == connected;
//  * an address has a non-empty host of host-name characters and a port in 1..65535.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "client/connection.h"
#include "client/replies.h"

namespace {

[[noreturn]] void fail(const char* what, std::string_view input) {
  std::fprintf(stderr, "fuzz_client_replies: %s: '%.*s'\n", what, static_cast<int>(input.size()),
               input.data());
  std::abort();
}

void check(std::uint8_t which, std::string_view text) {
  using namespace idm::client;
  switch (which % 10) {
    case 0: {
      const AxisStatus s = parse_status(text);
      if (s.position_valid != std::isfinite(s.position_m)) fail("position_valid vs position", text);
      break;
    }
    case 1: {
      const LoopStats l = parse_loop(text);
      if (!(l.bin_width_s > 0) || !std::isfinite(l.bin_width_s) || l.hist.size() > 1024)
        fail("a loop reply out of its promises", text);
      break;
    }
    case 2: {
      const ErrorReply e = parse_error(text);
      if (e.code == 0 && text.substr(0, 2) != "0,") fail("code 0 from another reply", text);
      if (e.text.size() > text.size()) fail("an error text longer than the reply", text);
      break;
    }
    case 3: {
      const SweepInfo s = parse_sweep(text);
      if (s.state.empty() || s.axis < -1) fail("a sweep reply out of its promises", text);
      break;
    }
    case 4: {
      const auto v = parse_number_list(text);
      if (v.empty()) fail("an empty list", text);
      break;
    }
    case 5: {
      const RegionReply r = parse_region(text);
      if (r.region != "CUTOFF" && r.region != "ONESTEP" && r.region != "MULTISTEP")
        fail("an unknown region", text);
      break;
    }
    case 6: {
      parse_key_values(text);
      const ClientTable t = parse_client_table(text);
      if (t.slots + t.stop_only + t.draining != t.connected)
        fail("a client table that does not add up", text);
      break;
    }
    case 7:
      parse_reply_number(text);
      parse_reply_count(text);
      break;
    case 8:
    case 9: {
      Address a;
      try {
        a = parse_host_port(text, 5025, which % 10 == 9);
      } catch (const AddressError&) {
        return;
      }
      if (a.host.empty() || a.port < (which % 10 == 9 ? 0 : 1) || a.port > 65535)
        fail("an address out of its promises", text);
      if (a.text().empty()) fail("an empty address text", text);
      return;
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const std::string_view text(reinterpret_cast<const char*>(data + 1), size - 1);
  try {
    check(data[0], text);
  } catch (const idm::client::ReplyError&) {
  }
  // Anything else thrown ends the run with an uncaught exception: a finding.
  return 0;
}
