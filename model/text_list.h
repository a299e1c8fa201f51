// Text that outside input shares: fields trimmed of blanks (the command protocol's lines, the
// dataset's CSV fields), and "start:stop:step" ranges, one expansion for idmd's command protocol
// (daemon/protocol.cpp, SWEEP lists) and the command-line tools (tools/cli.cpp, --freqs ...).
// Each caller keeps its own error format (a SCPI error code, a model::InputError); this says only
// what went wrong.
#pragma once

#include <cstddef>
#include <string_view>
#include <vector>

namespace idm::model {

// The blanks a field is trimmed of: spaces and tabs.
bool is_blank(char c);
std::string_view trim(std::string_view s);

// Splits "start:stop:step" at its two ':' into parts (not trimmed). False unless there are
// exactly two ':'.
bool split_range(std::string_view text, std::string_view (&parts)[3]);

enum class RangeError {
  None,
  BadRange,  // step <= 0 (or NaN), or stop < start
  TooMany,   // more than max_values values
};

// Appends start, start + step, ... up to stop inclusive (a stop within 1e-9 of a step counts),
// each rounded to 12 significant digits so that 0.05:0.95:0.1 gives 0.35 and not
// 0.35000000000000003. Nothing is appended on an error.
RangeError expand_range(double start, double stop, double step, std::size_t max_values,
                        std::vector<double>& out);

}  // namespace idm::model
