// Small helpers shared by the command-line tools: flags, numbers and lists with errors that name
// the argument and the allowed range. Errors are model::InputError; mains print them on one line.
#pragma once

#include <initializer_list>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "model/stage.h"

namespace idm::tools {

// --name value pairs after the subcommand; `repeatable` flags may appear more than once.
class Flags {
 public:
  // `switches`: names among `known` that take no value (--explain).
  Flags(int argc, char** argv, int first, const std::vector<std::string>& known,
        const std::vector<std::string>& repeatable = {},
        const std::vector<std::string>& switches = {});
  bool has(const std::string& name) const { return values_.count(name) > 0; }
  std::string text(const std::string& name) const;  // throws when missing
  std::vector<std::string> all(const std::string& name) const;
  double number(const std::string& name, double lo, double hi) const;
  double number_or(const std::string& name, double fallback, double lo, double hi) const;
  long integer(const std::string& name, long lo, long hi) const;
  long integer_or(const std::string& name, long fallback, long lo, long hi) const;
  std::vector<double> list(const std::string& name) const;

 private:
  std::map<std::string, std::vector<std::string>> values_;
};

// A finite number; "--freq: 'abc' is not a number".
double parse_number(const std::string& text, const std::string& what);
// "a,b,c" or "start:stop:step" (inclusive of stop within 1e-9 of a step).
std::vector<double> parse_list(const std::string& text, const std::string& what);

// A unit of length on the command line: its name and how many of it make a metre (exact in a
// double, so that a length divided by it is rounded once).
struct LengthUnit {
  std::string_view name;
  double per_metre;
};
// nm, um, mm or m; nullptr for anything else (names are case-sensitive: Mm would be megametres).
const LengthUnit* find_length_unit(std::string_view name);
// "nm, um, mm, m"
std::string length_unit_names();
// A length in metres from "250nm", "1.5mm", "-2e-6m", "1um": a plain decimal or exponent number
// and one of the units. A bare number is in `bare` (nullptr: refused, as ambiguous). InputError
// naming `what`, the text and the accepted units.
double parse_length(const std::string& text, const std::string& what, const LengthUnit* bare);
// `metres` in `unit`, 12 significant digits (1e-6 m in nm: "1000").
std::string format_length(double metres, const LengthUnit& unit);
// "nm/s, um/s, mm/s, m/s"
std::string speed_unit_names();
// A speed in m/s from "400um/s", "0.4mm/s", "4e-4m/s": a length as parse_length reads it, then
// "/s". A bare number is in `bare` per second (nullptr: refused, as ambiguous); a length without
// "/s" is refused. InputError naming `what`, the text and the accepted units.
double parse_speed(const std::string& text, const std::string& what, const LengthUnit* bare);
// The shortest text that reads back as exactly `value` ("2.5e-07"), for a protocol line.
std::string exact_number(double value);

// One subcommand of a tool: `tool NAME --flags...`; run gets the whole argv.
struct Subcommand {
  const char* name;
  int (*run)(int argc, char** argv);
};

// The main of a tool with subcommands: usage on no argument (exit 2) or --help, before or after
// the subcommand (`tool CMD --help`: exit 0, nothing run), an
// unknown name lists the allowed ones (exit 2), and an error is one line on stderr:
// "TOOL CMD: message" for bad input (model::InputError, exit 2), "TOOL CMD: error: message" for
// anything else (exit 1).
int run_subcommands(const char* tool, const char* usage, std::initializer_list<Subcommand> commands,
                    int argc, char** argv);

}  // namespace idm::tools
