// A schema for TOML configuration: one entry per key says where the value lives in the
// configuration struct, its type, range, unit and meaning. Parsing, range checks, the
// unknown-key check, defaults and the reference documentation all come from that one table.
//
// Errors are thrown as ConfigError with a message that names the file, line and key:
//   "drive.toml:12: injection.F_A: must be in [0, 200], got 350"
#pragma once

#include <toml++/toml.h>

#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace pmsm::app {

class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct ValueRange {
  double lo = -std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
  bool lo_open = false;

  [[nodiscard]] bool contains(double v) const {
    return (lo_open ? v > lo : v >= lo) && v <= hi;
  }
  [[nodiscard]] std::string describe() const;
};

[[nodiscard]] inline ValueRange positive(double hi = std::numeric_limits<double>::infinity()) {
  return {0.0, hi, true};
}
[[nodiscard]] inline ValueRange at_least(double lo, double hi = std::numeric_limits<double>::infinity()) {
  return {lo, hi, false};
}
[[nodiscard]] inline ValueRange between(double lo, double hi) { return {lo, hi, false}; }

template <typename Config>
class ConfigSchema {
 public:
  using RealAccess = std::function<double&(Config&)>;
  using IntAccess = std::function<int&(Config&)>;
  using BoolAccess = std::function<bool&(Config&)>;
  using StringAccess = std::function<std::string&(Config&)>;
  // A list of reals with a length limit, stored wherever the config keeps it.
  using ListSet = std::function<void(Config&, const std::vector<double>&)>;
  using ListGet = std::function<std::vector<double>(const Config&)>;
  using ChoiceSet = std::function<void(Config&, int)>;
  using ChoiceGet = std::function<int(const Config&)>;

  ConfigSchema& real(std::string key, RealAccess access, ValueRange range, std::string unit, std::string doc) {
    Entry e = make(std::move(key), Kind::kReal, std::move(unit), std::move(doc));
    e.range = range;
    e.real = std::move(access);
    entries_.push_back(std::move(e));
    return *this;
  }

  ConfigSchema& integer(std::string key, IntAccess access, ValueRange range, std::string doc) {
    Entry e = make(std::move(key), Kind::kInteger, "", std::move(doc));
    e.range = range;
    e.integer = std::move(access);
    entries_.push_back(std::move(e));
    return *this;
  }

  ConfigSchema& boolean(std::string key, BoolAccess access, std::string doc) {
    Entry e = make(std::move(key), Kind::kBoolean, "", std::move(doc));
    e.boolean = std::move(access);
    entries_.push_back(std::move(e));
    return *this;
  }

  ConfigSchema& string(std::string key, StringAccess access, std::string doc) {
    Entry e = make(std::move(key), Kind::kString, "", std::move(doc));
    e.string = std::move(access);
    entries_.push_back(std::move(e));
    return *this;
  }

  ConfigSchema& choice(std::string key, std::vector<std::pair<std::string, int>> names, ChoiceGet get,
                       ChoiceSet set, std::string doc) {
    Entry e = make(std::move(key), Kind::kChoice, "", std::move(doc));
    e.choices = std::move(names);
    e.choice_get = std::move(get);
    e.choice_set = std::move(set);
    entries_.push_back(std::move(e));
    return *this;
  }

  ConfigSchema& list(std::string key, std::size_t min_size, std::size_t max_size, ValueRange range, ListGet get,
                     ListSet set, std::string unit, std::string doc) {
    Entry e = make(std::move(key), Kind::kList, std::move(unit), std::move(doc));
    e.range = range;
    e.min_size = min_size;
    e.max_size = max_size;
    e.list_get = std::move(get);
    e.list_set = std::move(set);
    entries_.push_back(std::move(e));
    return *this;
  }

  // Applies every key of `table` found in the schema to `config`. Keys under one of
  // `foreign_tables` (e.g. "plant") are left for someone else. `key_prefix` is how the
  // table's keys are named in messages when it is itself nested in a file ("controller.").
  // Throws ConfigError.
  void apply(const toml::table& table, Config& config, std::string_view source,
             const std::vector<std::string>& foreign_tables = {}, std::string_view key_prefix = {}) const {
    check_unknown(table, "", source, foreign_tables, key_prefix);
    for (const Entry& e : entries_) {
      const toml::node_view<const toml::node> node = table.at_path(e.key);
      if (!node) {
        continue;
      }
      apply_entry(e, *node.node(), config, source, key_prefix);
    }
  }

  // Markdown table of every key with its default (from `defaults`), range and meaning.
  [[nodiscard]] std::string markdown(const Config& defaults) const;

  [[nodiscard]] std::vector<std::string> keys() const {
    std::vector<std::string> out;
    for (const Entry& e : entries_) {
      out.push_back(e.key);
    }
    return out;
  }

 private:
  enum class Kind { kReal, kInteger, kBoolean, kString, kChoice, kList };

  struct Entry {
    std::string key;
    Kind kind = Kind::kReal;
    std::string unit;
    std::string doc;
    ValueRange range{};
    std::size_t min_size = 0;
    std::size_t max_size = 0;
    RealAccess real;
    IntAccess integer;
    BoolAccess boolean;
    StringAccess string;
    std::vector<std::pair<std::string, int>> choices;
    ChoiceGet choice_get;
    ChoiceSet choice_set;
    ListGet list_get;
    ListSet list_set;
  };

  static Entry make(std::string key, Kind kind, std::string unit, std::string doc) {
    Entry e;
    e.key = std::move(key);
    e.kind = kind;
    e.unit = std::move(unit);
    e.doc = std::move(doc);
    return e;
  }

  [[nodiscard]] static std::string where(std::string_view source, const toml::node& node, std::string_view key,
                                         std::string_view prefix) {
    // The file the node came from (a scenario may inherit keys from a base file).
    const auto& region = node.source();
    const std::string file = region.path && !region.path->empty() ? *region.path : std::string(source);
    const std::string line = region.begin.line > 0 ? ":" + std::to_string(region.begin.line) : "";
    return file + line + ": " + std::string(prefix) + std::string(key) + ": ";
  }

  static double number_of(const Entry& e, const toml::node& node, std::string_view source, std::string_view prefix) {
    if (const auto* i = node.as_integer()) {
      return static_cast<double>(i->get());
    }
    if (const auto* f = node.as_floating_point()) {
      return f->get();
    }
    throw ConfigError(where(source, node, e.key, prefix) + "expected a number, got " + type_name(node));
  }

  static std::string type_name(const toml::node& node) {
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

  void apply_entry(const Entry& e, const toml::node& node, Config& config, std::string_view source,
                   std::string_view prefix) const {
    const std::string at = where(source, node, e.key, prefix);
    switch (e.kind) {
      case Kind::kReal: {
        const double v = number_of(e, node, source, prefix);
        if (!std::isfinite(v) || !e.range.contains(v)) {
          throw ConfigError(at + "must be " + e.range.describe() + ", got " + format_number(v));
        }
        e.real(config) = v;
        break;
      }
      case Kind::kInteger: {
        const auto* i = node.as_integer();
        if (i == nullptr) {
          throw ConfigError(at + "expected an integer, got " + type_name(node));
        }
        const auto v = static_cast<double>(i->get());
        if (!e.range.contains(v)) {
          throw ConfigError(at + "must be " + e.range.describe() + ", got " + std::to_string(i->get()));
        }
        e.integer(config) = static_cast<int>(i->get());
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
      case Kind::kString: {
        const auto* s = node.as_string();
        if (s == nullptr) {
          throw ConfigError(at + "expected a string, got " + type_name(node));
        }
        e.string(config) = s->get();
        break;
      }
      case Kind::kChoice: {
        const auto* s = node.as_string();
        if (s == nullptr) {
          throw ConfigError(at + "expected one of " + choice_list(e) + ", got " + type_name(node));
        }
        for (const auto& [name, value] : e.choices) {
          if (name == s->get()) {
            e.choice_set(config, value);
            return;
          }
        }
        throw ConfigError(at + "expected one of " + choice_list(e) + ", got \"" + s->get() + "\"");
      }
      case Kind::kList: {
        const auto* a = node.as_array();
        if (a == nullptr) {
          throw ConfigError(at + "expected an array of numbers, got " + type_name(node));
        }
        if (a->size() < e.min_size || a->size() > e.max_size) {
          throw ConfigError(at + "expected " + std::to_string(e.min_size) + " to " + std::to_string(e.max_size) +
                            " values, got " + std::to_string(a->size()));
        }
        std::vector<double> values;
        for (const toml::node& item : *a) {
          const double v = number_of(e, item, source, prefix);
          if (!std::isfinite(v) || !e.range.contains(v)) {
            throw ConfigError(at + "every value must be " + e.range.describe() + ", got " + format_number(v));
          }
          values.push_back(v);
        }
        e.list_set(config, values);
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

  static std::string format_number(double v) {
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, "%g", v);
    return buffer;
  }

  void check_unknown(const toml::table& table, const std::string& prefix, std::string_view source,
                     const std::vector<std::string>& foreign_tables, std::string_view key_prefix) const {
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
          check_unknown(*sub, key, source, foreign_tables, key_prefix);
          continue;
        }
        throw ConfigError(where(source, node, key, key_prefix) + "expected a table (section)");
      }
      throw ConfigError(where(source, node, key, key_prefix) + "unknown key" + suggestion(key, key_prefix));
    }
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
    return best <= 3 ? " (did you mean " + std::string(prefix) + best_key + "?)" : "";
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

inline std::string ValueRange::describe() const {
  const bool has_lo = std::isfinite(lo);
  const bool has_hi = std::isfinite(hi);
  char buffer[96];
  if (has_lo && has_hi) {
    std::snprintf(buffer, sizeof buffer, "in %s%g, %g]", lo_open ? "(" : "[", lo, hi);
  } else if (has_lo) {
    std::snprintf(buffer, sizeof buffer, "%s %g", lo_open ? ">" : ">=", lo);
  } else if (has_hi) {
    std::snprintf(buffer, sizeof buffer, "<= %g", hi);
  } else {
    return "any number";
  }
  return buffer;
}

template <typename Config>
std::string ConfigSchema<Config>::markdown(const Config& defaults) const {
  Config copy = defaults;
  std::string out = "| key | default | range | meaning |\n|---|---|---|---|\n";
  for (const Entry& e : entries_) {
    std::string value;
    std::string range;
    switch (e.kind) {
      case Kind::kReal:
        value = format_number(e.real(copy)) + (e.unit.empty() ? "" : " " + e.unit);
        range = e.range.describe();
        break;
      case Kind::kInteger:
        value = std::to_string(e.integer(copy));
        range = e.range.describe();
        break;
      case Kind::kBoolean:
        value = e.boolean(copy) ? "true" : "false";
        break;
      case Kind::kString:
        value = "\"" + e.string(copy) + "\"";
        break;
      case Kind::kChoice: {
        const int v = e.choice_get(copy);
        for (const auto& [name, number] : e.choices) {
          if (number == v) value = "\"" + name + "\"";
        }
        range = choice_list(e);
        break;
      }
      case Kind::kList: {
        value = "[";
        for (double x : e.list_get(copy)) {
          value += (value.size() > 1 ? ", " : "") + format_number(x);
        }
        value += "]" + (e.unit.empty() ? "" : " " + e.unit);
        range = std::to_string(e.min_size) + "–" + std::to_string(e.max_size) + " values, each " + e.range.describe();
        break;
      }
    }
    out += "| `" + e.key + "` | " + value + " | " + range + " | " + e.doc + " |\n";
  }
  return out;
}

}  // namespace pmsm::app
