// A simulation scenario: the plant (a realism profile plus overrides), the controller (the
// same sections as pmsm-thermald's configuration), and what happens over time: speed or
// torque set-points, ambient temperature, the calibration at a known temperature, and the
// thermal acceleration. docs/scenarios.md describes the format.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "controller_config.hpp"
#include "pmsm/core/supervisor.hpp"
#include "pmsm/plant/config.hpp"

namespace pmsm::app {

struct ProfilePoint {
  double time_s = 0.0;
  double value = 0.0;
};

// Piecewise-linear in time, held constant outside its points.
struct Profile {
  std::vector<ProfilePoint> points;
  [[nodiscard]] double at(double t_s) const;
  [[nodiscard]] bool empty() const { return points.empty(); }
};

struct ScenarioConfig {
  std::string name = "unnamed";
  std::string description;
  double duration_s = 10.0;
  double thermal_acceleration = 1.0;   // applied to the plant and the controller's model alike
  double ambient_C = 25.0;
  Profile ambient_profile;              // overrides ambient_C when given
  // Operation.
  core::DriveMode mode = core::DriveMode::kSpeed;
  Profile speed_rad_s;                  // mechanical, for speed mode
  Profile torque_Nm;                    // for torque mode
  bool calibrate = true;                // calibrate Rs0 at the start, at the known temperature
  double calibrate_at_s = 0.5;
  // Run the calibration at real thermal time (acceleration 1 in the plant and the
  // controller's model alike), as it would be on a machine: a two-second calibration then
  // barely warms the winding, where under test acceleration it would last thermal minutes.
  bool calibration_real_time = true;
  // Metrics.
  double log_period_s = 0.02;
  double error_threshold_C = 40.0;      // winding errors count where the truth is above this
  double disturbance_window_s = 0.05;   // moving-average window for speed/torque disturbance
  double rated_torque_Nm = 37.9;        // 11.9 kW at 314 rad/s (Table I)
};

struct Scenario {
  ScenarioConfig scenario;
  plant::PlantConfig plant;
  ControllerConfig controller;
  // The drive's supervisor: pmsm-thermald's defaults for the drive (default_supervisor_config),
  // with the scenario's [supervisor] keys, every one of the daemon's but command_timeout_s.
  // (load_scenario fills it in; a Scenario built in code sets it from its controller, or it keeps
  // core::SupervisorConfig's own values, which are no drive's defaults.)
  core::SupervisorConfig supervisor;
  std::filesystem::path source;
  // Every file the scenario is read from or keeps its state in: itself, its bases, its CSV
  // files, the plant profile and the drive's calibration and thermal-state files (an output
  // must not be written over one of them).
  std::vector<std::filesystem::path> files;
};

// Loads a scenario file. Paths inside it (plant profile, CSV files) are relative to the
// file. Throws ConfigError naming the file, line and key.
[[nodiscard]] Scenario load_scenario(const std::filesystem::path& path);
[[nodiscard]] Scenario parse_scenario(std::string_view toml_text, const std::filesystem::path& source);

// The schema of the [scenario] and [operation] keys (for docs/scenarios.md).
[[nodiscard]] std::string scenario_keys_markdown();

}  // namespace pmsm::app
