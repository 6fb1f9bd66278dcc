// Helpers shared by the configuration tests: the fixture directory and the message of the
// configuration error a call throws.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>

#include "scenario.hpp"

namespace pmsm::app::test {

inline const std::filesystem::path kConfigDir = std::filesystem::path(PMSM_SOURCE_DIR) / "tests/unit/data/config";

// Message of the ConfigError (plant, controller or scenario) that f throws; "" if none.
template <typename F>
std::string error_of(F f) {
  try {
    f();
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

// Parses inline scenario text as if it were the file `name` in the fixture directory (so
// relative paths resolve there) and returns the error message, "" if none.
inline std::string inline_error(std::string_view text, const std::string& name = "inline.toml") {
  return error_of([&] { (void)parse_scenario(text, kConfigDir / name); });
}

inline std::string path_of(const std::string& name) { return (kConfigDir / name).string(); }

}  // namespace pmsm::app::test
