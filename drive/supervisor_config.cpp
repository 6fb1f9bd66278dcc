#include "supervisor_config.hpp"

#include <string>
#include <vector>

#include <toml++/toml.h>

#include "config_schema.hpp"
#include "key_rules.hpp"

namespace pmsm::app {

namespace {

// The daemon's supervisor.* keys on a SupervisorConfig of its own (a scenario's section).
const ConfigSchema<core::SupervisorConfig>& scenario_supervisor_schema() {
  static const ConfigSchema<core::SupervisorConfig> schema = [] {
    ConfigSchema<core::SupervisorConfig> c;
    add_supervisor_keys<core::SupervisorConfig>(c, [](core::SupervisorConfig& s) -> core::SupervisorConfig& { return s; });
    return c;
  }();
  return schema;
}

constexpr std::string_view kCommandTimeoutKey = "supervisor.command_timeout_s";

}  // namespace

std::string scenario_supervisor_keys_markdown(const core::SupervisorConfig& defaults) {
  // The daemon's table's rows but the one key a scenario refuses.
  return scenario_supervisor_schema().markdown_rows(defaults, kCommandTimeoutKey);
}

core::SupervisorConfig parse_scenario_supervisor(const toml::table& root, std::string_view source,
                                                 core::SupervisorConfig defaults) {
  const ConfigSchema<core::SupervisorConfig>& schema = scenario_supervisor_schema();
  // The schema's keys are the file's dotted paths ("supervisor.x"), applied to the whole file with
  // every other top-level table left to its own reader: messages as for the scenario's own
  // sections (a `supervisor = 5` is "expected a table (section)").
  std::vector<std::string> others;
  for (const auto& [key, node] : root) {
    if (key.str() != "supervisor") {
      others.emplace_back(key.str());
    }
  }
  std::string errors;
  // The daemon's command timeout, which a scenario cannot judge, named with its reason beside the
  // section's other mistakes (not instead of them).
  const toml::table* section = root.get_as<toml::table>("supervisor");
  const toml::node* timeout = section != nullptr ? section->get("command_timeout_s") : nullptr;
  if (timeout != nullptr) {
    errors = common::node_location(*timeout, source) +
             "supervisor.command_timeout_s: a scenario takes every supervisor.* key of pmsm-thermald but this one: its "
             "drive gets no DRIVE_COMMAND stream (its set-points are [operation]), so the timeout would never be "
             "judged; delete the key";
  }
  // (The schema knows the key, so that the file's other mistakes keep their lines and order.)
  try {
    schema.apply(root, defaults, source, others);
  } catch (const ConfigError& e) {
    errors += (errors.empty() ? "" : "\n") + std::string(e.what());
  }
  if (!errors.empty()) {
    throw ConfigError(errors);
  }
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
