// A Session over a FakeInstrument, fed bytes as a client would send them (the protocol and
// session tests).
#pragma once

#include <string>
#include <string_view>

#include "daemon/protocol.h"
#include "tests/daemon/fake_instrument.h"

namespace idm::daemon::testing {

struct Harness {
  FakeInstrument fake;
  Session session{fake};

  std::string send(std::string_view bytes) {
    std::string out;
    session.receive(bytes, out);
    return out;
  }
  std::string line(const std::string& l) { return send(l + "\n"); }
  // The next error's code, popped with SYST:ERR?.
  int next_error() {
    const std::string r = line("SYST:ERR?");
    return std::stoi(r);
  }
  std::string next_error_text() { return line("SYST:ERR?"); }
};

inline int count_lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

}  // namespace idm::daemon::testing
