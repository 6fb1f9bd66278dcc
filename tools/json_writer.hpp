// A small streaming JSON writer for the command-line tools' --json output (objects, arrays,
// numbers, strings, booleans). Non-finite numbers are written as null: JSON has no NaN, and
// a missing value must not look like a plausible number.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace pmsm::app {

class JsonWriter {
 public:
  JsonWriter& begin_object();
  JsonWriter& end_object();
  JsonWriter& begin_array();
  JsonWriter& end_array();
  JsonWriter& key(std::string_view name);
  JsonWriter& value(double number);
  JsonWriter& value(std::int64_t number);
  JsonWriter& value(std::uint64_t number);
  JsonWriter& value(int number) { return value(static_cast<std::int64_t>(number)); }
  JsonWriter& value(bool flag);
  JsonWriter& value(std::string_view text);
  JsonWriter& value(const char* text) { return value(std::string_view(text)); }
  JsonWriter& null();

  template <typename T>
  JsonWriter& field(std::string_view name, T&& v) {
    key(name);
    return value(std::forward<T>(v));
  }

  [[nodiscard]] const std::string& str() const { return out_; }

 private:
  void separate();
  std::string out_;
  std::vector<bool> first_;  // per open container: nothing written yet
  bool after_key_ = false;
};

// JSON string escaping.
[[nodiscard]] std::string json_escape(std::string_view text);

}  // namespace pmsm::app
