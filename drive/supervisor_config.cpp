#include "supervisor_config.hpp"

#include <string>

#include "config_schema.hpp"
#include "key_rules.hpp"

namespace pmsm::app {
namespace {

using S = core::SupervisorConfig;

ConfigSchema<S> build(SupervisorKeys which) {
  ConfigSchema<S> c;
  c.real("dc_bus_min_V", [](S& s) -> double& { return s.dc_bus_min_V; }, between(0, 10000), "V",
         "DC-bus under-voltage trip (default: 0.6 x controller.control.nominal_dc_bus_V).");
  c.real("dc_bus_max_V", [](S& s) -> double& { return s.dc_bus_max_V; }, between(0, 10000), "V",
         "DC-bus over-voltage trip (default: 1.25 x nominal, at most 98 % of the DC-bus ADC's full scale).");
  c.real("overcurrent_A", [](S& s) -> double& { return s.overcurrent_A; }, positive(100000), "A",
         "Phase-current trip (default: 90 % of the current ADC's range).");
  c.real("current_sum_max_A", [](S& s) -> double& { return s.current_sum_max_A; }, positive(100000), "A",
         "|ia + ib + ic| above this: a phase-current sensor is broken (default: 10 % of the ADC's range).");
  c.real("current_offset_max_A", [](S& s) -> double& { return s.current_offset_max_A; }, positive(100000), "A",
         "A phase current sensor whose power-up offset (its mean reading with the gates off) lies further from zero "
         "than this is broken or stuck: CURRENT_OFFSET fault, the gates stay off until a restart (default: 5 % of the "
         "ADC's range).");
  c.real("ambient_min_C", [](S& s) -> double& { return s.ambient_min_C; }, between(-50, 200), "C",
         "The ambient / coolant sensor (in SENSOR_SAMPLE) reading below this is implausible: AMBIENT_IMPLAUSIBLE fault.");
  c.real("ambient_max_C", [](S& s) -> double& { return s.ambient_max_C; }, between(-50, 200), "C",
         "The ambient / coolant sensor reading above this is implausible: AMBIENT_IMPLAUSIBLE fault. (Both within "
         "[-50, 200] C, the T0 a calibration on the ambient may store: a wider window let one store a calibration the "
         "next start refused.)");
  c.real("max_speed_rad_s", [](S& s) -> double& { return s.max_speed_rad_s; }, positive(100000), "rad/s",
         "Mechanical speed the encoder may show; a larger step between samples is an encoder-jump fault (default: 3 x rated).");
  c.real("overspeed_rad_s", [](S& s) -> double& { return s.overspeed_rad_s; }, between(0, 100000), "rad/s",
         "Mechanical speed over about 1 ms of encoder counts above which the drive trips: OVERSPEED fault, gates off (an "
         "overhauling load, a runaway in torque control; default: 1.5 x rated; 0: off).");
  c.integer("output_feedback_periods", [](S& s) -> int& { return s.output_feedback_periods; }, between(0, 100000),
            "Samples in a row that report the gates off (SENSOR_SAMPLE OutputEnabled) while the drive has enabled them, "
            "or on while it holds them off: OUTPUT_FEEDBACK fault (an open enable chain, a safe torque off, a stage's own "
            "latched fault; a stage that ignores the enable, a stuck report); 0: not judged.");
  c.integer("sensor_timeout_periods", [](S& s) -> int& { return s.sensor_timeout_periods; }, between(1, 100000),
            "Missing samples in a row before the sensor-timeout fault (gates off).");
  c.integer("sensor_recovery_periods", [](S& s) -> int& { return s.sensor_recovery_periods; }, between(1, 100000),
            "Samples in a row after which a sensor timeout clears itself.");
  if (which == SupervisorKeys::kDaemon) {
    c.real("command_timeout_s", [](S& s) -> double& { return s.command_timeout_s; }, between(0, 3600), "s",
           "Enabled without a valid, fresh DRIVE_COMMAND this long: command-timeout fault, gates off (0: off).");
  }
  c.real("trip_temp_C", [](S& s) -> double& { return s.trip_temp_C; }, between(-50, 400), "C",
         "Winding-estimate trip (default: controller.derating.limit_C + 25 C; derating starts below).");
  c.real("trip_hysteresis_C", [](S& s) -> double& { return s.trip_hysteresis_C; }, between(0, 100), "C",
         "An over-temperature fault may be cleared this far below the trip.");
  return c;
}

}  // namespace

const ConfigSchema<core::SupervisorConfig>& supervisor_schema(SupervisorKeys which) {
  static const ConfigSchema<S> daemon = build(SupervisorKeys::kDaemon);
  static const ConfigSchema<S> scenario = build(SupervisorKeys::kScenario);
  return which == SupervisorKeys::kDaemon ? daemon : scenario;
}

core::SupervisorConfig parse_supervisor_config(const toml::table& root, std::string_view source,
                                               core::SupervisorConfig defaults, SupervisorKeys which) {
  const toml::table* table = common::optional_section(root, "supervisor", source);
  if (table == nullptr) {
    return defaults;
  }
  if (which == SupervisorKeys::kScenario) {
    if (const auto given = table->get("command_timeout_s"); given != nullptr) {
      throw ConfigError(common::node_location(*given, source) +
                        "supervisor.command_timeout_s: a scenario takes every supervisor.* key of pmsm-thermald but this "
                        "one: its drive gets no DRIVE_COMMAND stream (its set-points are [operation]), so the timeout "
                        "would never be judged; delete the key");
    }
  }
  supervisor_schema(which).apply(*table, defaults, source, {}, "supervisor.");
  return defaults;
}

std::string check_supervisor_own_rules(const core::SupervisorConfig& s, const toml::table& root, std::string_view source) {
  common::KeyRules rules(root, source);
  if (!(s.ambient_min_C < s.ambient_max_C)) {
    rules.with({"supervisor.ambient_min_C", "supervisor.ambient_max_C"}, [&](const auto& value) {
      return value("supervisor.ambient_min_C", s.ambient_min_C, "C") + " must be below " +
             value("supervisor.ambient_max_C", s.ambient_max_C, "C") + ": every ambient reading would be implausible";
    });
  }
  return rules.errors();
}

std::string check_supervisor_rules(const core::SupervisorConfig& s, const ControllerConfig& controller,
                                   const toml::table& root, std::string_view source) {
  common::KeyRules rules(root, source);
  constexpr std::string_view kMinFrom = "0.6 x controller.control.nominal_dc_bus_V";
  constexpr std::string_view kMaxFrom =
      "the lower of 1.25 x controller.control.nominal_dc_bus_V and 0.98 x controller.sensors.dc_bus_full_scale_V";
  constexpr std::string_view kRatedSpeed = "controller.motor.rated_speed_rad_s";
  if (!(s.dc_bus_min_V < s.dc_bus_max_V)) {
    rules.with({"supervisor.dc_bus_min_V", "supervisor.dc_bus_max_V", "controller.control.nominal_dc_bus_V",
                "controller.sensors.dc_bus_full_scale_V"},
               [&](const auto& value) {
                 return value("supervisor.dc_bus_min_V", s.dc_bus_min_V, "V", kMinFrom) + " must be below " +
                        value("supervisor.dc_bus_max_V", s.dc_bus_max_V, "V", kMaxFrom);
               });
  } else if (controller.nominal_dc_bus_V < s.dc_bus_min_V || controller.nominal_dc_bus_V > s.dc_bus_max_V) {
    rules.with({"controller.control.nominal_dc_bus_V", "supervisor.dc_bus_min_V", "supervisor.dc_bus_max_V",
                "controller.sensors.dc_bus_full_scale_V"},
               [&](const auto& value) {
                 return value("controller.control.nominal_dc_bus_V", controller.nominal_dc_bus_V, "V") + " lies outside " +
                        value("supervisor.dc_bus_min_V", s.dc_bus_min_V, "V", kMinFrom) + " .. " +
                        value("supervisor.dc_bus_max_V", s.dc_bus_max_V, "V", kMaxFrom) + ": the drive would trip at once";
               });
  }
  if (s.dc_bus_max_V >= controller.sensors.dc_bus_full_scale_V) {
    rules.with({"supervisor.dc_bus_max_V", "controller.sensors.dc_bus_full_scale_V"}, [&](const auto& value) {
      return value("supervisor.dc_bus_max_V", s.dc_bus_max_V, "V", kMaxFrom) + " must be below " +
             value("controller.sensors.dc_bus_full_scale_V", controller.sensors.dc_bus_full_scale_V, "V") +
             ": a saturated ADC reading never shows an over-voltage";
    });
  }
  constexpr std::string_view kOvercurrentFrom = "90 % of controller.sensors.current_range_A";
  if (s.overcurrent_A >= controller.sensors.current_range_A) {
    rules.with({"supervisor.overcurrent_A", "controller.sensors.current_range_A"}, [&](const auto& value) {
      return value("supervisor.overcurrent_A", s.overcurrent_A, "A", kOvercurrentFrom) + " must be below " +
             value("controller.sensors.current_range_A", controller.sensors.current_range_A, "A") +
             ": a saturated ADC reading is never a valid current";
    });
  } else if (const double limit_A = controller.drive.derating.max_current_A; s.overcurrent_A <= limit_A) {
    rules.with({"supervisor.overcurrent_A", "controller.derating.max_current_A", "controller.sensors.current_range_A"},
               [&](const auto& value) {
                 return value("supervisor.overcurrent_A", s.overcurrent_A, "A", kOvercurrentFrom) + " must be above " +
                        value("controller.derating.max_current_A", limit_A, "A") +
                        ": the drive would trip below its own current limit";
               });
  }
  const std::string max_speed_from = "3 x " + std::string(kRatedSpeed);
  const std::string overspeed_from = "1.5 x " + std::string(kRatedSpeed);
  if (s.overspeed_rad_s >= s.max_speed_rad_s) {
    rules.with({"supervisor.overspeed_rad_s", "supervisor.max_speed_rad_s", kRatedSpeed}, [&](const auto& value) {
      return value("supervisor.overspeed_rad_s", s.overspeed_rad_s, "rad/s", overspeed_from) + " must be below " +
             value("supervisor.max_speed_rad_s", s.max_speed_rad_s, "rad/s", max_speed_from) +
             ": beyond that a step of the encoder is an encoder jump, not a speed";
    });
  }
  if (const double limit = controller.drive.speed_limit_rad_s; s.overspeed_rad_s > 0.0 && limit >= s.overspeed_rad_s) {
    rules.with({"controller.control.speed_limit_rad_s", "supervisor.overspeed_rad_s", kRatedSpeed},
               [&](const auto& value) {
                 return value("controller.control.speed_limit_rad_s", limit, "rad/s", "1.2 x " + std::string(kRatedSpeed)) +
                        " must be below " + value("supervisor.overspeed_rad_s", s.overspeed_rad_s, "rad/s", overspeed_from) +
                        ": the shaft would trip OVERSPEED before the drive limits its speed";
               });
  }
  if (s.trip_temp_C <= controller.drive.derating.limit_C) {
    rules.with({"supervisor.trip_temp_C", "controller.derating.limit_C"}, [&](const auto& value) {
      return value("supervisor.trip_temp_C", s.trip_temp_C, "C") + " must be above " +
             value("controller.derating.limit_C", controller.drive.derating.limit_C, "C") +
             ": the drive derates before it trips";
    });
  }
  return rules.errors();
}

}  // namespace pmsm::app
