// The controller's configuration file: the drive's commissioned motor model, sensor scaling,
// control, injection, estimator, thermal model, calibration and derating. The same sections
// configure pmsm-thermald and the [controller] part of a simulation scenario.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include <toml++/toml.h>

#include "config_schema.hpp"
#include "pmsm/core/drive_controller.hpp"

namespace pmsm::app {

// How the controller turns ADC codes into physical values: its own nominal calibration (the
// plant's gain errors stay invisible to it, as a real sensor's would).
struct SensorScaling {
  int current_adc_bits = 12;
  double current_range_A = 200.0;   // full scale is +-range
  int dc_bus_adc_bits = 12;
  double dc_bus_full_scale_V = 1000.0;
  double offset_calibration_s = 0.05;  // current-ADC offsets averaged with the gates off at start
};

struct ControllerConfig {
  core::DriveConfig drive{};
  SensorScaling sensors{};
  double nominal_dc_bus_V = 650.0;
  // The calibration procedure's injection magnitude: at no load the whole current budget is
  // free, and a larger F makes the bridge's zero-current band matter less (docs/estimator.md).
  double calibration_f_A = 50.0;
  // Unless injection.vx_initial_V is given, the inverter-error prior starts at what the
  // dead-time compensation assumes at the nominal bus voltage.
  bool vx_initial_from_compensation = true;
};

// The schema of every controller key (docs/configuration.md is generated from it).
[[nodiscard]] const ConfigSchema<ControllerConfig>& controller_schema();

// The top-level sections the controller schema owns.
[[nodiscard]] const std::vector<std::string>& controller_sections();

// Fills the fields that follow from others (the controller's Ld, Lq and flux linkage in every
// component, periods, pole pairs) and checks rules that involve several keys. Throws
// ConfigError naming the keys.
void finalize(ControllerConfig& config, std::string_view source);

// Parses the controller sections of `table`; sections in `foreign` belong to someone else.
[[nodiscard]] ControllerConfig parse_controller_config(const toml::table& table, std::string_view source,
                                                       const std::vector<std::string>& foreign,
                                                       std::string_view key_prefix = {});

[[nodiscard]] ControllerConfig default_controller_config();

}  // namespace pmsm::app
