// What a configuration struct or a header needs of the configuration schema engine
// (config_schema.hpp) without toml++, whose header costs every translation unit that includes
// it about 3 s of compile time: the one error type, time tables, value ranges and a declaration
// of ConfigSchema. A header that names toml's types includes toml_fwd.hpp.
#pragma once

#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>
#include <string_view>

namespace pmsm::common {

// The one error type of every configuration file (drive, plant, scenario).
class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// One point of a time table: load steps, drive cycles, speed and set-point profiles.
struct TimePoint {
  double time_s = 0.0;
  double value = 0.0;
};

// A closed or lower-open numeric interval; infinite ends mean "no bound".
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

// The largest stator resistance any configuration, stored calibration or planning option
// accepts: one bound, so that a motor the drive's configuration takes can reload the
// calibration it stored (the file's was 10 ohm, the keys' 100) and the plant takes it too.
inline constexpr double kMaxStatorResistance_ohm = 100.0;
// The largest inertia, the drive's (motor.inertia_kg_m2: what its speed loop is designed for)
// and the plant's alike: a conveyor, a mill or a winder reflects more than 100 kg m^2 to the
// motor (a newcomer's downhill conveyor 142), which the drive refused while the plant took it.
inline constexpr double kMaxInertia_kg_m2 = 1e3;
// ... and the smallest value of a physical quantity the configurations accept, far below every
// real machine: `> 0` let 5e-324 through (motor.ld_H = 5e-324 passed --check, and the drive's
// first step divided it into a non-finite voltage and tripped INTERNAL). The planning options
// take the same floors.
inline constexpr double kMinStatorResistance_ohm = 1e-6;
inline constexpr double kMinInductance_H = 1e-9;
inline constexpr double kMinEmfConstant_V_s_per_rad = 1e-6;
inline constexpr double kMinInertia_kg_m2 = 1e-9;
inline constexpr double kMinMotorCurrent_A = 1e-3;
inline constexpr double kMinMotorSpeed_rad_s = 1e-3;
inline constexpr double kMinHeatCapacity_J_K = 1e-3;
inline constexpr double kMinThermalResistance_K_W = 1e-6;
// A DC bus below a volt drives no machine (1e-300 V passed, and the voltage limits divided by it).
inline constexpr double kMinDcBus_V = 1.0;

// "%g" of a number, as every message and table prints it.
[[nodiscard]] inline std::string format_number(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%g", v);
  return buffer;
}

// Text for a Markdown table cell: a '|' would end the cell (and shift every cell after it).
[[nodiscard]] inline std::string markdown_cell(std::string_view text) {
  std::string out;
  for (const char ch : text) {
    if (ch == '|') {
      out += '\\';
    }
    out += ch;
  }
  return out;
}

// Input echoed in a message, cut to its first `max` bytes with the length of the rest said: a
// 10 MB line must not make a 10 MB message.
[[nodiscard]] inline std::string excerpt(std::string_view text, std::size_t max = 80) {
  if (text.size() <= max) {
    return std::string(text);
  }
  return std::string(text.substr(0, max)) + "... (" + std::to_string(text.size()) + " bytes)";
}

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
    return "a finite number";
  }
  return buffer;
}

// The schema of one configuration struct (config_schema.hpp).
template <typename Config>
class ConfigSchema;

}  // namespace pmsm::common
