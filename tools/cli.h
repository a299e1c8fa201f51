// Small helpers shared by the command-line tools: flags, numbers and lists with errors that name
// the argument and the allowed range. Errors are model::InputError; mains print them on one line.
#pragma once

#include <initializer_list>
#include <map>
#include <string>
#include <vector>

#include "model/stage.h"

namespace idm::tools {

// --name value pairs after the subcommand; `repeatable` flags may appear more than once.
class Flags {
 public:
  Flags(int argc, char** argv, int first, const std::vector<std::string>& known,
        const std::vector<std::string>& repeatable = {});
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
