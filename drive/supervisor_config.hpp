// The supervisor's keys, [supervisor] in pmsm-thermald's file and in a scenario: one schema and
// one set of rules for both, so that a trip level a test engineer simulates is read, checked and
// refused exactly as the daemon reads it.
#pragma once

#include <functional>
#include <string>
#include <string_view>

#include "config_schema.hpp"
#include "controller_config.hpp"
#include "pmsm/core/supervisor.hpp"

namespace pmsm::app {

// Adds [supervisor]'s keys, named "supervisor.dc_bus_min_V" and so on, to `schema`, reaching the
// supervisor's configuration through `get`: pmsm-thermald's schema holds them among its own
// sections (one list of bad keys in the file's order), a scenario's supervisor schema alone.
template <typename Config>
void add_supervisor_keys(ConfigSchema<Config>& c, const std::function<core::SupervisorConfig&(Config&)>& get) {
  using common::between;
  using common::positive;
  const auto real = [&](const char* key, double core::SupervisorConfig::*field, common::ValueRange range, const char* unit,
                        const char* doc) {
    c.real(std::string("supervisor.") + key, [get, field](Config& config) -> double& { return get(config).*field; },
           range, unit, doc);
  };
  const auto integer = [&](const char* key, int core::SupervisorConfig::*field, common::ValueRange range, const char* doc) {
    c.integer(std::string("supervisor.") + key, [get, field](Config& config) -> int& { return get(config).*field; },
              range, doc);
  };
  using S = core::SupervisorConfig;
  real("dc_bus_min_V", &S::dc_bus_min_V, between(0, 10000), "V",
       "DC-bus under-voltage trip (default: 0.6 x controller.control.nominal_dc_bus_V).");
  real("dc_bus_max_V", &S::dc_bus_max_V, between(0, 10000), "V",
       "DC-bus over-voltage trip (default: 1.25 x nominal, at most 98 % of the DC-bus ADC's full scale).");
  real("overcurrent_A", &S::overcurrent_A, positive(100000), "A",
       "Phase-current trip (default: 90 % of the current ADC's range).");
  real("current_sum_max_A", &S::current_sum_max_A, positive(100000), "A",
       "|ia + ib + ic| above this: a phase-current sensor is broken (default: 10 % of the ADC's range).");
  real("current_offset_max_A", &S::current_offset_max_A, positive(100000), "A",
       "A phase current sensor whose power-up offset (its mean reading with the gates off) lies further from zero "
       "than this is broken or stuck: CURRENT_OFFSET fault, the gates stay off until a restart (default: 5 % of the "
       "ADC's range).");
  real("ambient_min_C", &S::ambient_min_C, between(-50, 200), "C",
       "The ambient / coolant sensor (in SENSOR_SAMPLE) reading below this is implausible: AMBIENT_IMPLAUSIBLE fault.");
  real("ambient_max_C", &S::ambient_max_C, between(-50, 200), "C",
       "The ambient / coolant sensor reading above this is implausible: AMBIENT_IMPLAUSIBLE fault. (Both within "
       "[-50, 200] C, the T0 a calibration on the ambient may store: a wider window let one store a calibration the "
       "next start refused.)");
  real("max_speed_rad_s", &S::max_speed_rad_s, positive(100000), "rad/s",
       "Mechanical speed the encoder may show; a larger step between samples is an encoder-jump fault (default: 3 x rated).");
  real("overspeed_rad_s", &S::overspeed_rad_s, between(0, 100000), "rad/s",
       "Mechanical speed over about 1 ms of encoder counts above which the drive trips: OVERSPEED fault, gates off (an "
       "overhauling load, a runaway in torque control; default: 1.5 x rated; 0: off).");
  integer("output_feedback_periods", &S::output_feedback_periods, between(0, 100000),
          "Samples in a row that report the gates off (SENSOR_SAMPLE OutputEnabled) while the drive has enabled them, "
          "or on while it holds them off: OUTPUT_FEEDBACK fault (an open enable chain, a safe torque off, a stage's own "
          "latched fault; a stage that ignores the enable, a stuck report); 0: not judged.");
  integer("sensor_timeout_periods", &S::sensor_timeout_periods, between(1, 100000),
          "Missing samples in a row before the sensor-timeout fault (gates off).");
  integer("sensor_recovery_periods", &S::sensor_recovery_periods, between(1, 100000),
          "Samples in a row after which a sensor timeout clears itself.");
  real("command_timeout_s", &S::command_timeout_s, between(0, 3600), "s",
       "Enabled without a valid, fresh DRIVE_COMMAND this long: command-timeout fault, gates off (0: off).");
  real("trip_temp_C", &S::trip_temp_C, between(-50, 400), "C",
       "Winding-estimate trip (default: controller.derating.limit_C + 25 C; derating starts below).");
  real("trip_hysteresis_C", &S::trip_hysteresis_C, between(0, 100), "C",
       "An over-temperature fault may be cleared this far below the trip.");
}

// A scenario's [supervisor]: `defaults` (the daemon's for the scenario's drive) with the keys of
// `root`'s [supervisor] section applied (`root`: the whole file), every one of the daemon's but
// supervisor.command_timeout_s, which is refused with its reason. Throws ConfigError naming every
// bad key at once.
[[nodiscard]] core::SupervisorConfig parse_scenario_supervisor(const toml::table& root, std::string_view source,
                                                               core::SupervisorConfig defaults);
// The reference table's rows of those keys (Markdown, without a header: config-keys scenario
// appends them to the scenario's table), with `defaults` as the default column: a scenario's
// drive takes the daemon's defaults for its own motor and bus.
[[nodiscard]] std::string scenario_supervisor_keys_markdown(const core::SupervisorConfig& defaults);

// Every broken rule between the supervisor's keys and the drive's ("controller." keys of
// `root`), one line each, located and worded as common::KeyRules does; "" when none.
[[nodiscard]] std::string check_supervisor_rules(const core::SupervisorConfig& supervisor,
                                                 const ControllerConfig& controller, const toml::table& root,
                                                 std::string_view source);

// The rules between the supervisor's own keys alone (the ambient window), which need no drive:
// one line each, "" when none.
[[nodiscard]] std::string check_supervisor_own_rules(const core::SupervisorConfig& supervisor, const toml::table& root,
                                                     std::string_view source);

}  // namespace pmsm::app
