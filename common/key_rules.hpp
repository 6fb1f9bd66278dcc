// Rules between configuration keys (a trip below the limit it guards, a period shorter than the
// control period, ...), each broken one a line of one message: located at the line of the first
// of its keys the file gives, and naming every key with its value and where that value comes
// from, so that a broken rule says which line to change even when a default broke it.
// Shared by pmsm-thermald's file and the simulator's scenarios, which read the same sections.
#pragma once

#include <initializer_list>
#include <string>
#include <string_view>

#include "config_schema.hpp"
#include "config_types.hpp"

namespace pmsm::common {

class KeyRules {
 public:
  // `root`: the whole file (its keys are dotted paths from the top); `source`: its name.
  KeyRules(const toml::table& root, std::string_view source) : root_(root), source_(source) {}
  KeyRules(toml::table&& root, std::string_view source) = delete;  // it keeps a reference

  // A broken rule at the line of `key` when the file gives it, else at the file.
  void at(std::string_view key, const std::string& text) { add(key_location(root_, key, source_), text); }
  // A broken rule of the file alone.
  void at_file(const std::string& text) { add(source_ + ": ", text); }

  // A broken rule on `keys`, located at the line of the first of them the file gives (the file
  // alone where it gives none: defaults broke it), its text made by `text(value)`:
  // value(key, v, unit, how) names a key with its value and where that comes from,
  // "supervisor.x (v unit)" for the key the message is located at, "(v unit, bad.toml:3)" for
  // another the file gives, "(v unit, its default)" or "(v unit, its default: how)" for one it
  // does not.
  template <typename Text>
  void with(std::initializer_list<std::string_view> keys, const Text& text) {
    const std::string_view at_key = first_given(root_, keys);
    const auto value = [&](std::string_view key, double v, std::string_view unit, std::string_view how = {}) {
      std::string from;
      if (!root_.at_path(key)) {
        from = how.empty() ? std::string(", its default") : ", its default: " + std::string(how);
      } else if (key != at_key) {
        from = key_location(root_, key, source_);
        from = ", " + from.substr(0, from.size() - 2);  // "bad.toml:3: " less its ": "
      }
      std::string out(key);
      out += " (" + format_number(v);
      if (!unit.empty()) {
        out += ' ';
        out += unit;
      }
      return out + from + ")";
    };
    const std::string message = text(value);
    if (at_key.empty()) {
      at_file(message);
    } else {
      at(at_key, message);
    }
  }

  // Broken rules another check found, one a line ("" adds nothing), in their turn.
  void append(const std::string& lines) {
    if (!lines.empty()) {
      errors_ += (errors_.empty() ? "" : "\n") + lines;
    }
  }

  // The first of `keys` that `root` gives, or "" when it gives none.
  [[nodiscard]] static std::string_view first_given(const toml::table& root, std::initializer_list<std::string_view> keys) {
    for (const std::string_view key : keys) {
      if (root.at_path(key)) {
        return key;
      }
    }
    return {};
  }
  // "file:line: " of the first of `keys` that `root` gives, else "source: ": where a refusal that
  // follows from several keys is located.
  [[nodiscard]] static std::string location_of_first(const toml::table& root, std::initializer_list<std::string_view> keys,
                                                     std::string_view source) {
    const std::string_view key = first_given(root, keys);
    return key.empty() ? std::string(source) + ": " : key_location(root, key, source);
  }

  // Every broken rule so far, one a line ("" when none).
  [[nodiscard]] const std::string& errors() const noexcept { return errors_; }
  [[nodiscard]] bool any() const noexcept { return !errors_.empty(); }

 private:
  void add(const std::string& location, const std::string& text) {
    errors_ += (errors_.empty() ? "" : "\n") + location + text;
  }

  const toml::table& root_;
  std::string source_;
  std::string errors_;
};

}  // namespace pmsm::common
