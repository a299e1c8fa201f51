// Parameter tables: every config struct declares its keys once, in a table next to the struct
// (name, unit, range, default, one line of doc, and where the value lives), and the YAML reader,
// the range check of values set in code, the error messages and config/README.md's rows all come
// from that one table (the ArduPilot AP_Param idea), so they cannot drift apart.
//
//   static const ParamTable<RealtimeConfig> kTable({
//       real<RealtimeConfig>("period_s", "s", {1e-5, 0.1}, "the loop's period",
//                            [](auto& c) -> auto& { return c.period_s; }),
//       ...});
//   kTable.read(node, file, "realtime", config);  // unknown keys, types, ranges: InputError
//   kTable.validate(config, "realtime");          // values set in code
//   kTable.markdown();                            // | key | unit | default | range | meaning |
//
// A key whose allowed values depend on other values (min_freq_hz <= max_freq_hz, a soft limit
// within the stage's travel) carries Relations: each gives the values allowed given the others,
// and says which in words. check_relations() (after a section is read, and any value it depends on
// is in the struct) and validate() check them; the message names the key, its value and the range
// left by its own range and its relations, and the README's range column lists them.
#pragma once

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "model/range.h"
#include "model/stage.h"
#include "model/yaml_util.h"

namespace idm::model {

// A bound on a number that depends on other values of the struct (another key, or what the rest
// of the document fixes and the parser put into the struct): `bound` gives the values allowed,
// which the key's own range narrows further; `text` says which ("<= max_freq_hz"), in the README's
// range column and in the message. zero_exempt: 0 is the key's "off" or "the default" and is
// allowed whatever the bound.
template <typename S>
struct Relation {
  std::string text;
  std::function<Range(const S&)> bound;
  bool zero_exempt = false;
};

template <typename S>
struct Param {
  std::string name;
  std::string unit;          // "m", "Hz", "s", "count", "1", "bool", "" (text)
  std::string range;         // as the README and messages show it
  std::string doc;           // one line
  std::string default_text;  // "" -> show(S{})
  std::function<void(S&, const YAML::Node&, const std::string& file, const std::string& key)> read;
  std::function<void(const S&, const std::string& key)> check;  // throws InputError
  // Numbers only (real, integer): stores a value set at run time (a protocol command) after the
  // same range check as a file's; InputError naming `key` otherwise.
  std::function<void(S&, double, const std::string& key)> assign;
  std::function<std::string(const S&)> show;
  // Numbers (real, integer): the key's own range and its value, which relations compare.
  Range limits;
  std::function<double(const S&)> number;
  std::vector<Relation<S>> relations;

  // The range column: the own range and every relation ("(0, 0.001]; <= max_stroke_m", "[0,
  // 0.001]; 0 or >= one count").
  std::string range_text() const {
    std::string out = range;
    for (const Relation<S>& r : relations) out += (r.zero_exempt ? "; 0 or " : "; ") + r.text;
    return out;
  }
  // "" when the value of `s` satisfies every relation, else why not: "VALUE is out of range,
  // allowed RANGE (RELATIONS)", RANGE the own range narrowed by every relation.
  std::string relation_error(const S& s) const {
    if (relations.empty() || !number) return {};
    const double v = number(s);
    Range allowed = limits;
    bool broken = false, zero_exempt = true;
    std::string why;
    for (const Relation<S>& r : relations) {
      const Range b = r.bound(s);
      allowed = allowed.intersect(b);
      why += (why.empty() ? "" : "; ") + r.text;
      zero_exempt = zero_exempt && r.zero_exempt;
      broken = broken || !b.contains(v);
    }
    if (!broken || (zero_exempt && v == 0)) return {};
    const bool empty = allowed.lo > allowed.hi ||
                       (allowed.lo == allowed.hi && (allowed.lo_open || allowed.hi_open));
    const std::string allowed_text = empty         ? std::string(zero_exempt ? "0 only" : "none")
                                     : zero_exempt ? "0 or " + allowed.text()
                                                   : allowed.text();
    return format_number(v) + " is out of range, allowed " + allowed_text + " (" + why + ")";
  }
};

template <typename S>
class ParamTable {
 public:
  explicit ParamTable(std::vector<Param<S>> params) : params_(std::move(params)) {}

  // Reads the map `node` into `out` (an absent or null node reads nothing). `section` prefixes
  // the keys in messages ("control" -> "control.max_retries"). An unknown key names the allowed
  // ones; a wrong type or a value out of range names the key, the line and the range.
  void read(const YAML::Node& node, const std::string& file, const std::string& section,
            S& out) const {
    if (!node.IsDefined() || node.IsNull()) return;
    if (!node.IsMap()) throw InputError(located(file, node, section, "expected a map"));
    for (const auto& kv : node) {
      const std::string name = kv.first.as<std::string>();
      const std::string key = section.empty() ? name : section + "." + name;
      const Param<S>* p = find(name);
      if (p == nullptr)
        throw InputError(located(file, kv.first, key, unknown_name(name, name_list())));
      if (!kv.second.IsDefined() || kv.second.IsNull())
        throw InputError(located(file, kv.first, key, "no value"));
      p->read(out, kv.second, file, key);
    }
  }
  // Checks values that did not come from a file (set in code): the first one out of range throws
  // InputError "SECTION.KEY: VALUE is out of range, allowed RANGE".
  void validate(const S& s, const std::string& section) const {
    for (const Param<S>& p : params_)
      if (p.check) p.check(s, section.empty() ? p.name : section + "." + p.name);
    check_relations(s, YAML::Node(YAML::NodeType::Undefined), "", section);
  }
  // Checks every key's relations (model::Relation) in `s`, read from the map `node` of `file`:
  // one broken throws InputError "FILE:LINE: SECTION.KEY: VALUE is out of range, allowed RANGE
  // (RELATIONS)", a key the file gives first (at its line; soft_upper_m: -2e-3 is named, not the
  // soft_lower_m it leaves no room for), else the first in the table (at the section's line).
  // Without a file (values set in code): "SECTION.KEY: ...".
  void check_relations(const S& s, const YAML::Node& node, const std::string& file,
                       const std::string& section) const {
    const auto given = [&node](const std::string& name) {
      if (node.IsDefined() && node.IsMap())
        for (const auto& kv : node)
          if (kv.first.IsScalar() && kv.first.Scalar() == name) return kv.second;
      return YAML::Node(YAML::NodeType::Undefined);
    };
    for (const bool in_file : {true, false})
      for (const Param<S>& p : params_) {
        const YAML::Node at = given(p.name);
        if (in_file && !at.IsDefined()) continue;
        const std::string why = p.relation_error(s);
        if (why.empty()) continue;
        const std::string key = section.empty() ? p.name : section + "." + p.name;
        if (file.empty()) throw InputError(key + ": " + why);
        throw InputError(located(file, at.IsDefined() ? at : node, key, why));
      }
  }
  // The README rows: "| key | unit | default | range | meaning |", keys prefixed with `prefix`.
  std::string markdown(const std::string& prefix = "") const {
    const S defaults{};
    std::string out;
    for (const Param<S>& p : params_) {
      const std::string def = p.default_text.empty() ? p.show(defaults) : p.default_text;
      out += "| " + prefix + p.name + " | " + p.unit + " | " + def + " | " + p.range_text() +
             " | " + p.doc + " |\n";
    }
    return out;
  }
  // Sets the number `name` of `s` to `value`, checked as a file's value is (the table's range, an
  // integer for a count): InputError "SHOWN: VALUE is out of range, allowed RANGE UNIT" leaves
  // `s` as it was. The one check of a setting a command changes (MOVE:WINDow, HOLD, ...).
  void set(S& s, const std::string& name, double value, const std::string& shown) const {
    const Param<S>* p = find(name);
    if (p == nullptr || !p->assign) throw InputError(shown + ": no such number setting");
    p->assign(s, value, shown);
  }
  const Param<S>* find(const std::string& name) const {
    for (const Param<S>& p : params_)
      if (p.name == name) return &p;
    return nullptr;
  }
  std::vector<std::string> name_list() const {
    std::vector<std::string> out;
    for (const Param<S>& p : params_) out.push_back(p.name);
    return out;
  }
  std::string names() const {
    std::string out;
    for (const Param<S>& p : params_) out += (out.empty() ? "" : ", ") + p.name;
    return out;
  }
  const std::vector<Param<S>>& params() const { return params_; }

 private:
  std::vector<Param<S>> params_;
};

// "| key | unit | default | range | meaning |" and its rule, for a table's rows.
std::string markdown_header();

// ---- builders ----
// `get` is a generic lambda returning a reference to the field: [](auto& c) -> auto& { ... }.

template <typename S, typename Get>
Param<S> real(const char* name, const char* unit, Range range, const char* doc, Get get) {
  Param<S> p;
  p.name = name;
  p.unit = unit;
  p.range = range.text();
  p.doc = doc;
  p.read = [range, get](S& s, const YAML::Node& v, const std::string& file,
                        const std::string& key) {
    const double x = read_double(v, file, key, -1e308, 1e308);
    if (!range.contains(x))
      throw InputError(
          located(file, v, key, format_number(x) + " is out of range, allowed " + range.text()));
    get(s) = x;
  };
  p.check = [range, get](const S& s, const std::string& key) {
    check_range("", key, get(s), range);
  };
  // The file's words for the same value, and the unit (a command's name does not carry it as a
  // key's does).
  p.assign = [range, get, unit = std::string(unit)](S& s, double x, const std::string& key) {
    if (!range.contains(x))
      throw InputError(key + ": " + format_number(x) + " is out of range, allowed " + range.text() +
                       (unit == "1" || unit.empty() ? "" : " " + unit));
    get(s) = x;
  };
  p.show = [get](const S& s) { return format_number(get(s)); };
  p.limits = range;
  p.number = [get](const S& s) { return static_cast<double>(get(s)); };
  return p;
}

template <typename S, typename Get>
Param<S> integer(const char* name, const char* unit, long lo, long hi, const char* doc, Get get) {
  Param<S> p;
  p.name = name;
  p.unit = unit;
  p.range = "[" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
  p.doc = doc;
  p.read = [lo, hi, get](S& s, const YAML::Node& v, const std::string& file,
                         const std::string& key) {
    using T = std::remove_reference_t<decltype(get(s))>;
    get(s) = static_cast<T>(read_integer(v, file, key, lo, hi));
  };
  p.check = [lo, hi, get](const S& s, const std::string& key) {
    const long long x = static_cast<long long>(get(s));
    if (x < lo || x > hi)
      throw InputError(key + ": " + std::to_string(x) + " is out of range, allowed [" +
                       std::to_string(lo) + ", " + std::to_string(hi) + "]");
  };
  p.assign = [lo, hi, get](S& s, double x, const std::string& key) {
    using T = std::remove_reference_t<decltype(get(s))>;
    const std::string range = "[" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
    if (x != std::floor(x))
      throw InputError(key + ": " + format_number(x) + " is not an integer, allowed " + range);
    if (!(x >= static_cast<double>(lo) && x <= static_cast<double>(hi)))
      throw InputError(key + ": " + format_number(x) + " is out of range, allowed " + range);
    get(s) = static_cast<T>(x);
  };
  p.show = [get](const S& s) { return std::to_string(get(s)); };
  p.limits = Range{static_cast<double>(lo), static_cast<double>(hi)};
  p.number = [get](const S& s) { return static_cast<double>(get(s)); };
  return p;
}

template <typename S, typename Get>
Param<S> boolean(const char* name, const char* doc, Get get) {
  Param<S> p;
  p.name = name;
  p.unit = "bool";
  p.range = "true, false";
  p.doc = doc;
  p.read = [get](S& s, const YAML::Node& v, const std::string& file, const std::string& key) {
    get(s) = read_bool(v, file, key);
  };
  p.show = [get](const S& s) { return std::string(get(s) ? "true" : "false"); };
  return p;
}

template <typename S, typename Get>
Param<S> text(const char* name, const char* doc, Get get, const char* range = "any text") {
  Param<S> p;
  p.name = name;
  p.unit = "";
  p.range = range;
  p.doc = doc;
  p.read = [get](S& s, const YAML::Node& v, const std::string& file, const std::string& key) {
    get(s) = read_string(v, file, key);
  };
  p.show = [get](const S& s) {
    const std::string& t = get(s);
    return t.empty() ? std::string("\"\"") : t;
  };
  return p;
}

// One of named values: choices = {{"synthetic", ClockMode::Synthetic}, ...}.
template <typename S, typename T, typename Get>
Param<S> choice(const char* name, std::vector<std::pair<std::string, T>> choices, const char* doc,
                Get get) {
  Param<S> p;
  p.name = name;
  p.unit = "";
  for (const auto& c : choices) p.range += (p.range.empty() ? "" : ", ") + c.first;
  p.doc = doc;
  p.read = [choices, get, allowed = p.range, what = std::string(name)](
               S& s, const YAML::Node& v, const std::string& file, const std::string& key) {
    const std::string t = read_string(v, file, key);
    for (const auto& c : choices)
      if (c.first == t) {
        get(s) = c.second;
        return;
      }
    throw InputError(located(file, v, key, "unknown " + what + " '" + t + "', allowed " + allowed));
  };
  p.show = [choices, get](const S& s) {
    for (const auto& c : choices)
      if (c.second == get(s)) return c.first;
    return std::string("?");
  };
  return p;
}

// A key read by its own function (a nested map, a pair of numbers): the range column says what
// it takes.
template <typename S>
Param<S> custom(
    const char* name, const char* unit, const char* range, const char* default_text,
    const char* doc,
    std::function<void(S&, const YAML::Node&, const std::string&, const std::string&)> read) {
  Param<S> p;
  p.name = name;
  p.unit = unit;
  p.range = range;
  p.doc = doc;
  p.default_text = default_text;
  p.read = std::move(read);
  p.show = [](const S&) { return std::string(); };
  return p;
}

// Builders' defaults: a `default_text` that replaces the value shown (defaults that depend on
// other keys, "stage.travel_m").
template <typename S>
Param<S> with_default(Param<S> p, const char* default_text) {
  p.default_text = default_text;
  return p;
}

// A relation for a number: `bound` (a callable S -> Range) gives the values allowed given the
// others; `text` says which.
template <typename S, typename Bound>
Param<S> with_relation(Param<S> p, const char* text, Bound bound, bool zero_exempt = false) {
  p.relations.push_back(Relation<S>{text, bound, zero_exempt});
  return p;
}

// The same for the key `name` among `params` (one lifted from a member's table); throws
// std::logic_error when there is none.
template <typename S, typename Bound>
void relate(std::vector<Param<S>>& params, const std::string& name, const char* text, Bound bound,
            bool zero_exempt = false) {
  for (Param<S>& p : params)
    if (p.name == name) {
      p.relations.push_back(Relation<S>{text, bound, zero_exempt});
      return;
    }
  throw std::logic_error("relate: no key " + name);
}

// The keys of a member struct's table as keys of the outer struct (flattened: control's
// max_retries is PositionerConfig's). `names`: only these (empty: all); `get` returns the member.
template <typename S, typename Sub, typename Get>
std::vector<Param<S>> lifted(const ParamTable<Sub>& sub, Get get,
                             const std::vector<std::string>& names = {}) {
  std::vector<Param<S>> out;
  const Sub defaults{};
  for (const Param<Sub>& q : sub.params()) {
    if (!names.empty() && std::find(names.begin(), names.end(), q.name) == names.end()) continue;
    Param<S> p;
    p.name = q.name;
    p.unit = q.unit;
    p.range = q.range;
    p.doc = q.doc;
    p.default_text = q.default_text.empty() ? q.show(defaults) : q.default_text;
    p.read = [r = q.read, get](S& s, const YAML::Node& v, const std::string& f,
                               const std::string& k) { r(get(s), v, f, k); };
    if (q.check) p.check = [c = q.check, get](const S& s, const std::string& k) { c(get(s), k); };
    if (q.assign)
      p.assign = [a = q.assign, get](S& s, double v, const std::string& k) { a(get(s), v, k); };
    p.show = [sh = q.show, get](const S& s) { return sh(get(s)); };
    p.limits = q.limits;
    if (q.number) p.number = [n = q.number, get](const S& s) { return n(get(s)); };
    for (const Relation<Sub>& r : q.relations)
      p.relations.push_back(
          Relation<S>{r.text, [b = r.bound, get](const S& s) { return b(get(s)); }, r.zero_exempt});
    out.push_back(std::move(p));
  }
  return out;
}

// A nested map `name:` read with the member struct's own table (control.calibration).
template <typename S, typename Sub, typename Get>
Param<S> nested(const char* name, const char* doc, const ParamTable<Sub>& sub, Get get) {
  Param<S> p;
  p.name = name;
  p.unit = "map";
  p.range = "keys: " + sub.names();
  p.doc = doc;
  p.default_text = "(below)";
  p.read = [&sub, get](S& s, const YAML::Node& v, const std::string& f, const std::string& k) {
    sub.read(v, f, k, get(s));
  };
  p.check = [&sub, get](const S& s, const std::string& k) { sub.validate(get(s), k); };
  p.show = [](const S&) { return std::string(); };
  return p;
}

// Concatenates lists of params.
template <typename S>
std::vector<Param<S>> join(std::vector<std::vector<Param<S>>> parts) {
  std::vector<Param<S>> out;
  for (auto& part : parts)
    for (auto& p : part) out.push_back(std::move(p));
  return out;
}

}  // namespace idm::model
