// The command protocol's line framing, parser and dispatcher: a Session (daemon/protocol.h) fed
// with the fuzzer's bytes, in pieces of any size, over the fake Instrument of the protocol tests.
//
// Input: byte 0 sets the size of the pieces the bytes arrive in (1..256, varying), byte 1 how many
// motion_done() polls a motion takes (0..3, so that *OPC? and *WAI wait); the rest is the stream.
//
// Invariants (daemon/protocol.h):
//  * every terminated line whose first word ends in '?' gets exactly one reply line, any other
//    line none (counted over the whole stream, *OPC? and *WAI waits drained);
//  * a reply line holds printable ASCII only;
//  * a line that does not parse, or whose header is no motion command, moves nothing: the
//    instrument sees at most one motion call per well-formed MOVE, MOVE:REL, STEP or SWEEP line;
//  * the error queue stays within its capacity; nothing throws out of the Session.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "daemon/protocol.h"
#include "tests/daemon/fake_instrument.h"

namespace {

using idm::daemon::header_matches;
using idm::daemon::looks_like_query;
using idm::daemon::ParsedLine;

[[noreturn]] void fail(const char* what, std::string_view detail = {}) {
  std::fprintf(stderr, "fuzz_protocol: %s: %.*s\n", what, static_cast<int>(detail.size()),
               detail.data());
  std::abort();
}

// The lines a Session must execute: every one ending in '\n' (a CR before it dropped).
struct Expected {
  std::size_t query_lines = 0;
  std::size_t motion_lines = 0;  // well-formed lines that may start a motion
  bool closed = false;  // a line that looks like HTTP closed the session: none after it runs
};

bool may_move(std::string_view line) {
  ParsedLine parsed;
  if (!idm::daemon::parse_line(line, parsed).ok() || parsed.query) return false;
  for (const char* pattern : {"MOVE[:ABSolute]", "MOVE:RELative", "STEP", "SWEEP"})
    if (header_matches(pattern, parsed.header)) return true;
  return false;
}

Expected expected_from(std::string_view stream) {
  Expected e;
  std::size_t start = 0;
  for (std::size_t nl = stream.find('\n'); nl != std::string_view::npos;
       start = nl + 1, nl = stream.find('\n', start)) {
    std::string_view line = stream.substr(start, nl - start);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (idm::daemon::looks_like_http(line) ||
        (line.size() > idm::daemon::kMaxLineBytes &&
         idm::daemon::looks_like_http(line.substr(0, idm::daemon::kMaxLineBytes)))) {
      e.closed = true;
      break;
    }
    e.query_lines += looks_like_query(line);
    e.motion_lines += may_move(line);
  }
  return e;
}

std::size_t count_lines(const std::string& replies) {
  std::size_t n = 0;
  for (char c : replies) {
    if (c == '\n') {
      ++n;
    } else if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) >= 0x7f) {
      fail("a reply holds a byte outside printable ASCII", replies);
    }
  }
  if (!replies.empty() && replies.back() != '\n') fail("a reply line without its newline", replies);
  return n;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  const std::size_t piece = 1 + data[0];
  const int polls = data[1] % 4;
  const std::string_view stream(reinterpret_cast<const char*>(data + 2), size - 2);

  idm::daemon::testing::FakeInstrument fake;
  fake.set_polls_until_done(polls);
  idm::daemon::Session session(fake);
  std::string replies;
  std::size_t at = 0, k = 0;
  while (at < stream.size()) {
    const std::size_t n = std::min(stream.size() - at, 1 + (piece * (k++ % 3 + 1)) % 257);
    session.receive(stream.substr(at, n), replies);
    at += n;
    if (session.errors().size() > idm::daemon::kErrorQueueCapacity) fail("error queue overflow");
    for (int p = 0; p < 2 && session.waiting(); ++p) session.poll(replies);
  }
  // Drain every wait: the fake finishes a motion after `polls` polls.
  for (int p = 0; p < 100000 && session.waiting(); ++p) session.poll(replies);
  if (session.waiting()) fail("a wait that never ends");

  const Expected e = expected_from(stream);
  const std::size_t last_newline = stream.rfind('\n');
  const std::string_view tail =
      last_newline == std::string_view::npos ? stream : stream.substr(last_newline + 1);
  // An unterminated last line already too long is reported at once, with its empty reply when
  // it is a query (it can never become a line the session executes).
  const bool early_overrun_reply =
      !e.closed && tail.size() > idm::daemon::kMaxLineBytes + 1 && looks_like_query(tail) &&
      !idm::daemon::looks_like_http(tail.substr(0, idm::daemon::kMaxLineBytes));
  const std::size_t got = count_lines(replies);
  if (got != e.query_lines + early_overrun_reply) {
    std::fprintf(stderr, "fuzz_protocol: %zu query lines, %zu reply lines\n", e.query_lines, got);
    fail("not one reply line per query line", replies);
  }
  if (fake.motion_calls() > e.motion_lines) {
    std::fprintf(stderr, "fuzz_protocol: %zu motion lines, %zu motion calls\n", e.motion_lines,
                 fake.motion_calls());
    fail("a motion from a line that is no well-formed motion command");
  }

  // The peer closes: whatever the session does with an unterminated last line, it says at most
  // one more line, and only for a query.
  std::string closing;
  session.end_of_input(closing);
  for (int p = 0; p < 100000 && session.waiting(); ++p) session.poll(closing);
  const std::size_t after = count_lines(closing);
  if (after > (looks_like_query(tail) && !early_overrun_reply ? 1u : 0u))
    fail("replies after the close", closing);
  return 0;
}
