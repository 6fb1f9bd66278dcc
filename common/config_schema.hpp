// The one schema engine for TOML configuration (drive, plant, scenarios): one entry per key
// says where the value lives in the configuration struct, its type, range, unit and meaning.
// Parsing, range checks (also of configurations built in code), the unknown-key check,
// defaults and the reference documentation all come from that one table.
//
// Errors are thrown as ConfigError with a message that names the file, line and key:
//   "drive.toml:12: injection.F_A: must be in [0, 200], got 350"
//
// Header only; depends on toml++ and the standard library (common/ may use nothing else).
// The types a configuration struct or a header needs (ConfigError, TimePoint, ranges) are in
// config_types.hpp, without toml++.
#pragma once

#include <toml++/toml.h>

#include "config_types.hpp"
#include "text_file.hpp"
#include "toml_depth.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace pmsm::common {

// Every configuration file is read through this: a missing file, a directory, a device
// (/dev/zero would be read forever) or a file beyond 256 MiB (hours of a 1 kHz drive cycle
// fit) is a ConfigError naming the path, never a hang or an exhausted memory. `what` names the file's role ("plant profile").
inline std::string read_config_file(const std::filesystem::path& path, std::string_view what) {
  std::string text;
  if (const std::string problem = read_text_file(path, text); !problem.empty()) {
    throw ConfigError(path.string() + ": " + std::string(what) + ": " + problem);
  }
  return text;
}

// "file:line: " of a node: the file it came from (a scenario may inherit keys from a base
// file), else `source`.
[[nodiscard]] inline std::string node_location(const toml::node& node, std::string_view source) {
  // Appended piece by piece: GCC 12 at -O3 took ":" + std::to_string(...) for an overlapping
  // memcpy (a false -Wrestrict warning in the release build, GCC bug 105329).
  const auto& region = node.source();
  std::string location = region.path && !region.path->empty() ? *region.path : std::string(source);
  if (region.begin.line > 0) {
    location += ':';
    location += std::to_string(region.begin.line);
  }
  location += ": ";
  return location;
}

// "file:line: " of `key` (a dotted path) in `table` when the file gives it, else "source: ".
[[nodiscard]] inline std::string key_location(const toml::table& table, std::string_view key, std::string_view source) {
  const auto node = table.at_path(key);
  return node ? node_location(*node.node(), source) : std::string(source) + ": ";
}

// "a string", "an array", ...: what a node is, for "expected X, got Y".
[[nodiscard]] inline std::string node_type_name(const toml::node& node) {
  switch (node.type()) {
    case toml::node_type::string: return "a string";
    case toml::node_type::integer: return "an integer";
    case toml::node_type::floating_point: return "a number";
    case toml::node_type::boolean: return "a boolean";
    case toml::node_type::array: return "an array";
    case toml::node_type::table: return "a table";
    default: return "a date or time";
  }
}

// Parses a configuration's text: a syntax error becomes a ConfigError naming file and line.
[[nodiscard]] inline toml::table parse_toml(std::string_view text, std::string_view source) {
  if (const auto deep = toml_key_depth_problem(text)) {
    throw ConfigError(toml_depth_message(*deep, source));  // (toml++ would overflow the stack)
  }
  try {
    return toml::parse(text, source);
  } catch (const toml::parse_error& e) {
    throw ConfigError(std::string(source) + ":" + std::to_string(e.source().begin.line) + ": " + std::string(e.description()));
  }
}

// A section another parser reads (a schema's foreign table, e.g. [controller] in the
// daemon's file): null when the file does not give it, an error naming file, line and key when
// the key is there but is not a table (`controller = "x"`, `[[controller]]`), which would
// otherwise be skipped with every key it was meant to hold.
[[nodiscard]] inline const toml::table* optional_section(const toml::table& root, std::string_view key,
                                                         std::string_view source) {
  const toml::node* node = root.get(key);
  if (node == nullptr) {
    return nullptr;
  }
  if (const toml::table* t = node->as_table()) {
    return t;
  }
  throw ConfigError(node_location(*node, source) + std::string(key) + ": expected a table (section [" + std::string(key) +
                    "]), got " + node_type_name(*node));
}

template <typename Config>
class ConfigSchema {
 public:
  static constexpr std::size_t kMaxListedErrors = 20;
  static constexpr std::size_t kMaxStringBytes = 4096;
  using RealAccess = std::function<double&(Config&)>;
  using OptionalRealAccess = std::function<std::optional<double>&(Config&)>;
  using IntAccess = std::function<int&(Config&)>;
  using SeedAccess = std::function<std::uint64_t&(Config&)>;
  using BoolAccess = std::function<bool&(Config&)>;
  using StringAccess = std::function<std::string&(Config&)>;
  using PathAccess = std::function<std::filesystem::path&(Config&)>;
  using Real3Access = std::function<std::array<double, 3>&(Config&)>;
  using IntListAccess = std::function<std::vector<int>&(Config&)>;
  using PointsAccess = std::function<std::vector<TimePoint>&(Config&)>;
  // A list of reals with a length limit, stored wherever the config keeps it.
  using ListSet = std::function<void(Config&, const std::vector<double>&)>;
  using ListGet = std::function<std::vector<double>(const Config&)>;
  using ChoiceSet = std::function<void(Config&, int)>;
  using ChoiceGet = std::function<int(const Config&)>;

  ConfigSchema& real(std::string key, RealAccess access, ValueRange range, std::string unit, std::string doc) {
    Entry& e = add(std::move(key), Kind::kReal, std::move(unit), std::move(doc));
    e.range = range;
    e.real = std::move(access);
    return *this;
  }

  // A real that may be absent; `when_absent` says in the docs what holds then.
  ConfigSchema& optional_real(std::string key, OptionalRealAccess access, ValueRange range, std::string unit,
                              std::string when_absent, std::string doc) {
    Entry& e = add(std::move(key), Kind::kOptionalReal, std::move(unit), std::move(doc));
    e.range = range;
    e.optional_real = std::move(access);
    e.when_absent = std::move(when_absent);
    return *this;
  }

  ConfigSchema& integer(std::string key, IntAccess access, ValueRange range, std::string doc) {
    Entry& e = add(std::move(key), Kind::kInteger, "", std::move(doc));
    e.range = range;
    e.integer = std::move(access);
    return *this;
  }

  // A non-negative 64-bit integer (random seeds).
  ConfigSchema& seed(std::string key, SeedAccess access, std::string doc) {
    Entry& e = add(std::move(key), Kind::kSeed, "", std::move(doc));
    e.range = at_least(0);
    e.seed = std::move(access);
    return *this;
  }

  ConfigSchema& boolean(std::string key, BoolAccess access, std::string doc) {
    Entry& e = add(std::move(key), Kind::kBoolean, "", std::move(doc));
    e.boolean = std::move(access);
    return *this;
  }

  ConfigSchema& string(std::string key, StringAccess access, std::string doc) {
    Entry& e = add(std::move(key), Kind::kString, "", std::move(doc));
    e.string = std::move(access);
    return *this;
  }

  // A file path, stored as given (the caller resolves relative paths).
  ConfigSchema& path(std::string key, PathAccess access, std::string doc) {
    Entry& e = add(std::move(key), Kind::kPath, "", std::move(doc));
    e.path = std::move(access);
    return *this;
  }

  ConfigSchema& choice(std::string key, std::vector<std::pair<std::string, int>> names, ChoiceGet get,
                       ChoiceSet set, std::string doc) {
    Entry& e = add(std::move(key), Kind::kChoice, "", std::move(doc));
    e.choices = std::move(names);
    e.choice_get = std::move(get);
    e.choice_set = std::move(set);
    return *this;
  }

  // Exactly three reals (one per phase a, b, c).
  ConfigSchema& real3(std::string key, Real3Access access, ValueRange range, std::string unit, std::string doc) {
    Entry& e = add(std::move(key), Kind::kReal3, std::move(unit), std::move(doc));
    e.range = range;
    e.real3 = std::move(access);
    return *this;
  }

  ConfigSchema& list(std::string key, std::size_t min_size, std::size_t max_size, ValueRange range, ListGet get,
                     ListSet set, std::string unit, std::string doc) {
    Entry& e = add(std::move(key), Kind::kList, std::move(unit), std::move(doc));
    e.range = range;
    e.min_size = min_size;
    e.max_size = max_size;
    e.list_get = std::move(get);
    e.list_set = std::move(set);
    return *this;
  }

  ConfigSchema& int_list(std::string key, std::size_t max_size, ValueRange range, IntListAccess access,
                         std::string doc) {
    Entry& e = add(std::move(key), Kind::kIntList, "", std::move(doc));
    e.range = range;
    e.max_size = max_size;
    e.int_list = std::move(access);
    return *this;
  }

  // A time table [[time_s, value], ...]: times >= 0 and ascending (equal times make a step),
  // every value within `range`.
  ConfigSchema& points(std::string key, ValueRange range, PointsAccess access, std::string unit, std::string doc) {
    Entry& e = add(std::move(key), Kind::kPoints, std::move(unit), std::move(doc));
    e.range = range;
    e.points = std::move(access);
    return *this;
  }

  // Applies every key of `table` found in the schema to `config`. Keys under one of
  // `foreign_tables` (e.g. "plant") are left for someone else. `key_prefix` is how the
  // table's keys are named in messages when it is itself nested in a file ("controller.").
  // Throws ConfigError naming every bad key of the table, one line each (a file with three
  // mistakes shows all three at once).
  void apply(const toml::table& table, Config& config, std::string_view source,
             const std::vector<std::string>& foreign_tables = {}, std::string_view key_prefix = {}) const {
    std::vector<LocatedError> errors;
    check_unknown(table, "", source, foreign_tables, key_prefix, errors);
    for (const Entry& e : entries_) {
      const toml::node_view<const toml::node> node = table.at_path(e.key);
      if (!node) {
        continue;
      }
      try {
        apply_entry(e, *node.node(), config, source, key_prefix);
      } catch (const ConfigError& error) {
        errors.push_back({order_of(*node.node(), source), error.what(), {}, false});
      }
    }
    if (!errors.empty()) {
      // In the file's order, unknown keys and bad values alike, as a compiler lists its errors.
      std::stable_sort(errors.begin(), errors.end(),
                       [](const LocatedError& a, const LocatedError& b) { return a.order < b.order; });
      // At most kMaxListedErrors: a file of 200,000 unknown keys printed 200,000 lines (and
      // looked for a suggestion for each of them, 17 s for 100,000).
      std::string all;
      for (std::size_t k = 0; k < errors.size() && k < kMaxListedErrors; ++k) {
        const LocatedError& error = errors[k];
        all += (k == 0 ? "" : "\n") + error.message;
        if (!error.unknown_key.empty()) {
          std::string hint = suggestion(error.unknown_key, key_prefix);
          if (hint.empty() && error.unknown_table) {
            hint = section_suggestion(error.unknown_key, key_prefix, foreign_tables);
          }
          all += hint;
        }
      }
      if (errors.size() > kMaxListedErrors) {
        all += "\n" + std::string(source) + ": " + std::to_string(errors.size() - kMaxListedErrors) + " more errors not listed";
      }
      throw ConfigError(all);
    }
  }

  // The range checks of apply() on a configuration built in code. Throws ConfigError
  // "<source>: <key>: must be ..., got ...".
  void validate(const Config& config, std::string_view source) const {
    Config copy = config;
    for (const Entry& e : entries_) {
      const std::string at = std::string(source) + (source.empty() ? "" : ": ") + e.key + ": ";
      auto check = [&](double v) {
        if (!std::isfinite(v) || !e.range.contains(v)) {
          throw ConfigError(at + "must be " + e.range.describe() + ", got " + format_number(v));
        }
      };
      switch (e.kind) {
        case Kind::kReal: check(e.real(copy)); break;
        case Kind::kOptionalReal:
          if (const std::optional<double>& v = e.optional_real(copy)) check(*v);
          break;
        case Kind::kInteger: check(e.integer(copy)); break;
        case Kind::kReal3:
          for (double v : e.real3(copy)) check(v);
          break;
        case Kind::kList:
          for (double v : e.list_get(copy)) check(v);
          break;
        case Kind::kIntList:
          for (int v : e.int_list(copy)) check(v);
          break;
        case Kind::kPoints:
          for (const TimePoint& p : e.points(copy)) check(p.value);
          break;
        case Kind::kSeed:
        case Kind::kBoolean:
        case Kind::kString:
        case Kind::kPath:
        case Kind::kChoice: break;
      }
    }
  }

  // Markdown table of every key with its default (from `defaults`), range and meaning.
  [[nodiscard]] std::string markdown(const Config& defaults) const {
    return "| key | default | range | meaning |\n|---|---|---|---|\n" + markdown_rows(defaults);
  }
  // The same table's rows alone, without the key `except` (empty: none), for a table that joins
  // another schema's keys to its own.
  [[nodiscard]] std::string markdown_rows(const Config& defaults, std::string_view except = {}) const;

  [[nodiscard]] std::vector<std::string> keys() const {
    std::vector<std::string> out;
    for (const Entry& e : entries_) {
      out.push_back(e.key);
    }
    return out;
  }

 private:
  enum class Kind { kReal, kOptionalReal, kInteger, kSeed, kBoolean, kString, kPath, kChoice, kReal3, kList,
                    kIntList, kPoints };

  struct Entry {
    std::string key;
    Kind kind = Kind::kReal;
    std::string unit;
    std::string doc;
    std::string when_absent;
    ValueRange range{};
    std::size_t min_size = 0;
    std::size_t max_size = 0;
    RealAccess real;
    OptionalRealAccess optional_real;
    IntAccess integer;
    SeedAccess seed;
    BoolAccess boolean;
    StringAccess string;
    PathAccess path;
    Real3Access real3;
    IntListAccess int_list;
    PointsAccess points;
    std::vector<std::pair<std::string, int>> choices;
    ChoiceGet choice_get;
    ChoiceSet choice_set;
    ListGet list_get;
    ListSet list_set;
  };

  Entry& add(std::string key, Kind kind, std::string unit, std::string doc) {
    Entry e;
    e.key = std::move(key);
    e.kind = kind;
    e.unit = std::move(unit);
    e.doc = std::move(doc);
    entries_.push_back(std::move(e));
    return entries_.back();
  }

  [[nodiscard]] static std::string where(std::string_view source, const toml::node& node, std::string_view key,
                                         std::string_view prefix) {
    // A key from the file is cut at 80 characters (a 1 MB quoted key was repeated whole).
    const bool cut = key.size() > 80;
    return node_location(node, source) + std::string(prefix) + std::string(key.substr(0, cut ? 72 : key.size())) +
           (cut ? "...: " : ": ");
  }

  // A finite number (integers are accepted where a number is expected).
  static double number_of(const toml::node& node, const std::string& at) {
    if (const auto* i = node.as_integer()) {
      return static_cast<double>(i->get());
    }
    if (const auto* f = node.as_floating_point()) {
      return f->get();  // NaN and infinities fail every range check
    }
    throw ConfigError(at + "expected a number, got " + type_name(node));
  }

  static std::int64_t integer_of(const toml::node& node, const std::string& at) {
    if (const auto* i = node.as_integer()) {
      return i->get();
    }
    throw ConfigError(at + "expected an integer, got " + type_name(node));
  }

  static std::string type_name(const toml::node& node) { return node_type_name(node); }

  static void check_range(const Entry& e, double v, const std::string& at, std::string_view what = "") {
    if (!std::isfinite(v) || !e.range.contains(v)) {
      throw ConfigError(at + std::string(what) + "must be " + e.range.describe() + ", got " + format_number(v));
    }
  }

  // An integer key's range, the value printed as the integer it is (4294967297, not 4.29497e+09).
  static void check_range(const Entry& e, std::int64_t v, const std::string& at, std::string_view what = "") {
    if (!e.range.contains(static_cast<double>(v))) {
      throw ConfigError(at + std::string(what) + "must be " + e.range.describe() + ", got " + std::to_string(v));
    }
  }

  static const toml::array& array_of(const toml::node& node, const std::string& at, std::string_view of) {
    const auto* a = node.as_array();
    if (a == nullptr) {
      throw ConfigError(at + "expected an array of " + std::string(of) + ", got " + type_name(node));
    }
    return *a;
  }

  void apply_entry(const Entry& e, const toml::node& node, Config& config, std::string_view source,
                   std::string_view prefix) const {
    const std::string at = where(source, node, e.key, prefix);
    switch (e.kind) {
      case Kind::kReal: {
        const double v = number_of(node, at);
        check_range(e, v, at);
        e.real(config) = v;
        break;
      }
      case Kind::kOptionalReal: {
        const double v = number_of(node, at);
        check_range(e, v, at);
        e.optional_real(config) = v;
        break;
      }
      case Kind::kInteger: {
        const std::int64_t v = integer_of(node, at);
        check_range(e, v, at);
        e.integer(config) = static_cast<int>(v);
        break;
      }
      case Kind::kSeed: {
        const std::int64_t v = integer_of(node, at);
        check_range(e, v, at);
        e.seed(config) = static_cast<std::uint64_t>(v);
        break;
      }
      case Kind::kBoolean: {
        const auto* b = node.as_boolean();
        if (b == nullptr) {
          throw ConfigError(at + "expected true or false, got " + type_name(node));
        }
        e.boolean(config) = b->get();
        break;
      }
      case Kind::kString:
      case Kind::kPath: {
        const auto* s = node.as_string();
        if (s == nullptr) {
          throw ConfigError(at + (e.kind == Kind::kPath ? "expected a file path (string), got " : "expected a string, got ") +
                            type_name(node));
        }
        // A control character has no place in a name, a path or an interface: a NUL cut the
        // text where the system read it (another file, a message's reason lost), a newline
        // split a report's line or a plot's command.
        const std::string& text = s->get();
        // Longer than any path the system takes (PATH_MAX): refused without echoing it (a 10 MB
        // interface name was repeated whole in the message, into the journal).
        if (text.size() > kMaxStringBytes) {
          throw ConfigError(at + "a text of " + std::to_string(text.size()) + " bytes, at most " +
                            std::to_string(kMaxStringBytes));
        }
        for (std::size_t k = 0; k < text.size(); ++k) {
          const auto ch = static_cast<unsigned char>(text[k]);
          if (ch < 0x20U || ch == 0x7fU) {
            char code[16];
            std::snprintf(code, sizeof code, "U+%04X", static_cast<unsigned>(ch));
            throw ConfigError(at + "contains a control character (" + code + ") at position " + std::to_string(k + 1));
          }
        }
        if (e.kind == Kind::kPath) {
          e.path(config) = std::filesystem::path(text);
        } else {
          e.string(config) = text;
        }
        break;
      }
      case Kind::kChoice: {
        const auto* s = node.as_string();
        if (s == nullptr) {
          throw ConfigError(at + "expected one of " + choice_list(e) + ", got " + type_name(node));
        }
        if (s->get().size() > 64) {
          throw ConfigError(at + "expected one of " + choice_list(e) + ", got a text of " + std::to_string(s->get().size()) +
                            " bytes");
        }
        for (const auto& [name, value] : e.choices) {
          if (name == s->get()) {
            e.choice_set(config, value);
            return;
          }
        }
        throw ConfigError(at + "expected one of " + choice_list(e) + ", got \"" + s->get() + "\"");
      }
      case Kind::kReal3: {
        const toml::array& a = array_of(node, at, "3 numbers (phases a, b, c)");
        if (a.size() != 3) {
          throw ConfigError(at + "expected an array of 3 numbers (phases a, b, c), got " + std::to_string(a.size()) +
                            " elements");
        }
        std::array<double, 3> v{};
        std::size_t k = 0;
        for (const toml::node& item : a) {
          const std::string item_at = where(source, item, e.key, prefix);
          v[k] = number_of(item, item_at);
          check_range(e, v[k], item_at, "every value ");
          ++k;
        }
        e.real3(config) = v;
        break;
      }
      case Kind::kList: {
        const toml::array& a = array_of(node, at, "numbers");
        if (a.size() < e.min_size || a.size() > e.max_size) {
          throw ConfigError(at + "expected " + std::to_string(e.min_size) + " to " + std::to_string(e.max_size) +
                            " values, got " + std::to_string(a.size()));
        }
        std::vector<double> values;
        for (const toml::node& item : a) {
          const std::string item_at = where(source, item, e.key, prefix);
          const double v = number_of(item, item_at);
          check_range(e, v, item_at, "every value ");
          values.push_back(v);
        }
        e.list_set(config, values);
        break;
      }
      case Kind::kIntList: {
        const toml::array& a = array_of(node, at, "integers");
        if (a.size() > e.max_size) {
          throw ConfigError(at + "at most " + std::to_string(e.max_size) + " values, got " + std::to_string(a.size()));
        }
        std::vector<int> values;
        for (const toml::node& item : a) {
          const std::string item_at = where(source, item, e.key, prefix);
          const std::int64_t v = integer_of(item, item_at);
          check_range(e, v, item_at, "every value ");
          values.push_back(static_cast<int>(v));
        }
        e.int_list(config) = std::move(values);
        break;
      }
      case Kind::kPoints: {
        const toml::array& a = array_of(node, at, "[time_s, value] pairs");
        std::vector<TimePoint> values;
        std::size_t k = 0;
        for (const toml::node& item : a) {
          // Counted from 1, "of" the total: no doubt which element is meant.
          const std::string element =
              where(source, item, e.key, prefix) + "element " + std::to_string(++k) + " of " + std::to_string(a.size()) + ": ";
          const auto* pair = item.as_array();
          if (pair == nullptr || pair->size() != 2) {
            throw ConfigError(element + "expected [time_s, value]");
          }
          double tv[2] = {0.0, 0.0};
          std::size_t n = 0;
          for (const toml::node& x : *pair) {
            tv[n++] = number_of(x, element);
          }
          const TimePoint p{tv[0], tv[1]};
          if (!std::isfinite(p.time_s) || p.time_s < 0.0) {
            throw ConfigError(element + "time must be >= 0, got " + format_number(p.time_s));
          }
          if (!values.empty() && p.time_s < values.back().time_s) {
            throw ConfigError(element + "times must be ascending, got " + format_number(p.time_s) + " after " +
                              format_number(values.back().time_s));
          }
          check_range(e, p.value, element, "value ");
          values.push_back(p);
        }
        e.points(config) = std::move(values);
        break;
      }
    }
  }

  static std::string choice_list(const Entry& e) {
    std::string out;
    for (const auto& [name, value] : e.choices) {
      out += (out.empty() ? "" : ", ") + std::string("\"") + name + "\"";
    }
    return out;
  }

  // An error with where it sorts: its line in `source`; after those, in the order found, one
  // from another file (a scenario's base) or without a line.
  struct LocatedError {
    std::size_t order = 0;
    std::string message;
    // An unknown key's name, for the "did you mean" that follows its message: found only for
    // the errors listed (the search costs a comparison with every key of the schema).
    std::string unknown_key;
    bool unknown_table = false;
  };
  static std::size_t order_of(const toml::node& node, std::string_view source) {
    const auto& region = node.source();
    const bool here = !region.path || region.path->empty() || *region.path == source;
    return here && region.begin.line > 0 ? static_cast<std::size_t>(region.begin.line)
                                         : std::numeric_limits<std::size_t>::max();
  }

  void check_unknown(const toml::table& table, const std::string& prefix, std::string_view source,
                     const std::vector<std::string>& foreign_tables, std::string_view key_prefix,
                     std::vector<LocatedError>& errors) const {
    for (const auto& [k, node] : table) {
      const std::string key = prefix.empty() ? std::string(k.str()) : prefix + "." + std::string(k.str());
      bool foreign = false;
      for (const std::string& f : foreign_tables) {
        foreign = foreign || key == f;
      }
      if (foreign) {
        continue;
      }
      bool known = false;
      bool is_section = false;
      for (const Entry& e : entries_) {
        known = known || e.key == key;
        is_section = is_section || e.key.rfind(key + ".", 0) == 0;
      }
      if (known) {
        continue;
      }
      if (is_section) {
        if (const auto* sub = node.as_table()) {
          check_unknown(*sub, key, source, foreign_tables, key_prefix, errors);
          continue;
        }
        errors.push_back({order_of(node, source), where(source, node, key, key_prefix) + "expected a table (section)", {}, false});
        continue;
      }
      errors.push_back({order_of(node, source), where(source, node, key, key_prefix) + "unknown key", key, node.is_table()});
    }
  }

  // An unknown table whose name is close to a section's ([cann], [controler.motor]): that
  // section, where suggestion() finds no key close to the table's name.
  [[nodiscard]] std::string section_suggestion(const std::string& key, std::string_view prefix,
                                               const std::vector<std::string>& foreign_tables) const {
    // A section of the same parent (a table under [startup] is not [startup] misspelt), within a
    // third of the name's length in edits (two letters of "io" made it "rt").
    const std::size_t dot = key.rfind('.');
    const std::string parent = dot == std::string::npos ? std::string() : key.substr(0, dot + 1);
    std::size_t best = std::max<std::size_t>(1, (key.size() - parent.size()) / 3) + 1;
    std::string best_section;
    auto consider = [&](const std::string& section) {
      const std::size_t sdot = section.rfind('.');
      const std::string sparent = sdot == std::string::npos ? std::string() : section.substr(0, sdot + 1);
      if (sparent != parent) {
        return;
      }
      if (const std::size_t d = edit_distance(key, section); d < best) {
        best = d;
        best_section = section;
      }
    };
    for (const Entry& e : entries_) {
      for (std::size_t at = e.key.find('.'); at != std::string::npos; at = e.key.find('.', at + 1)) {
        consider(e.key.substr(0, at));
      }
    }
    for (const std::string& f : foreign_tables) {
      consider(f);
    }
    return best_section.empty() ? std::string() : " (did you mean [" + std::string(prefix) + best_section + "]?)";
  }

  [[nodiscard]] std::string suggestion(const std::string& key, std::string_view prefix) const {
    // The known key with the smallest edit distance, if it is close.
    std::size_t best = std::string::npos;
    std::string best_key;
    for (const Entry& e : entries_) {
      const std::size_t d = edit_distance(key, e.key);
      if (d < best) {
        best = d;
        best_key = e.key;
      }
    }
    if (best > 3) {
      // A key given without its unit ("rs" for "rs_ohm", "winding_capacity" for
      // "winding_capacity_J_K"): the key that is this one plus its unit as keys spell units.
      for (const Entry& e : entries_) {
        if (!e.unit.empty() && e.key == key + "_" + unit_as_key(e.unit)) {
          return " (did you mean " + std::string(prefix) + e.key + "?)";
        }
      }
      return "";
    }
    return " (did you mean " + std::string(prefix) + best_key + "?)";
  }

  // A unit as the keys spell it: "J/K" -> "J_K", "W s^2/rad^2" -> "W_s2_rad2".
  static std::string unit_as_key(const std::string& unit) {
    std::string out;
    for (const char c : unit) {
      if (c == ' ' || c == '/') {
        out += '_';
      } else if (c != '^') {
        out += c;
      }
    }
    return out;
  }

  static std::size_t edit_distance(const std::string& a, const std::string& b) {
    std::vector<std::size_t> row(b.size() + 1);
    for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
    for (std::size_t i = 1; i <= a.size(); ++i) {
      std::size_t diagonal = row[0];
      row[0] = i;
      for (std::size_t j = 1; j <= b.size(); ++j) {
        const std::size_t up = row[j];
        row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0U : 1U)});
        diagonal = up;
      }
    }
    return row[b.size()];
  }

  std::vector<Entry> entries_;
};

template <typename Config>
std::string ConfigSchema<Config>::markdown_rows(const Config& defaults, std::string_view except) const {
  Config copy = defaults;
  auto with_unit = [](std::string value, const std::string& unit) { return unit.empty() ? value : value + " " + unit; };
  std::string out;
  for (const Entry& e : entries_) {
    if (!except.empty() && e.key == except) {
      continue;
    }
    std::string value;
    std::string range;
    switch (e.kind) {
      case Kind::kReal:
        value = with_unit(format_number(e.real(copy)), e.unit);
        range = e.range.describe();
        break;
      case Kind::kOptionalReal: {
        const std::optional<double>& v = e.optional_real(copy);
        value = v ? with_unit(format_number(*v), e.unit) : e.when_absent;
        range = e.range.describe();
        break;
      }
      case Kind::kInteger:
        value = std::to_string(e.integer(copy));
        range = e.range.describe();
        break;
      case Kind::kSeed:
        value = std::to_string(e.seed(copy));
        range = e.range.describe();
        break;
      case Kind::kBoolean:
        value = e.boolean(copy) ? "true" : "false";
        break;
      case Kind::kString:
        value = "\"" + e.string(copy) + "\"";
        break;
      case Kind::kPath:
        value = "\"" + e.path(copy).string() + "\"";
        break;
      case Kind::kChoice: {
        const int v = e.choice_get(copy);
        for (const auto& [name, number] : e.choices) {
          if (number == v) value = "\"" + name + "\"";
        }
        range = choice_list(e);
        break;
      }
      case Kind::kReal3: {
        const std::array<double, 3>& v = e.real3(copy);
        value = with_unit("[" + format_number(v[0]) + ", " + format_number(v[1]) + ", " + format_number(v[2]) + "]", e.unit);
        range = "3 values, each " + e.range.describe();
        break;
      }
      case Kind::kList: {
        value = "[";
        for (double x : e.list_get(copy)) {
          value += (value.size() > 1 ? ", " : "") + format_number(x);
        }
        value = with_unit(value + "]", e.unit);
        range = std::to_string(e.min_size) + "–" + std::to_string(e.max_size) + " values, each " + e.range.describe();
        break;
      }
      case Kind::kIntList: {
        value = "[";
        for (int x : e.int_list(copy)) {
          value += (value.size() > 1 ? ", " : "") + std::to_string(x);
        }
        value += "]";
        range = "0–" + std::to_string(e.max_size) + " values, each " + e.range.describe();
        break;
      }
      case Kind::kPoints: {
        value = "[";
        for (const TimePoint& p : e.points(copy)) {
          value += (value.size() > 1 ? ", " : "") + ("[" + format_number(p.time_s) + ", " + format_number(p.value) + "]");
        }
        value += "]";
        range = "[time_s, value] pairs, times ascending, values " + e.range.describe();
        break;
      }
    }
    // (the formulas such as ω·|ω| have their '|' escaped)
    out += "| `" + e.key + "` | " + value + " | " + range + " | " + markdown_cell(e.doc) + " |\n";
  }
  return out;
}

}  // namespace pmsm::common
