// The supervisor's keys, [supervisor] in pmsm-thermald's file and in a scenario: one schema and
// one set of rules for both, so that a trip level a test engineer simulates is read, checked and
// refused exactly as the daemon reads it.
#pragma once

#include <string>
#include <string_view>

#include "config_types.hpp"
#include "toml_fwd.hpp"
#include "controller_config.hpp"
#include "pmsm/core/supervisor.hpp"

namespace pmsm::app {

// Which file reads [supervisor]: pmsm-thermald's takes every key; a scenario all but
// command_timeout_s (a simulated drive gets no DRIVE_COMMAND stream: its set-points are the
// scenario's [operation]).
enum class SupervisorKeys { kDaemon, kScenario };

// The schema of [supervisor]'s keys, named without the section ("dc_bus_min_V"): applied to the
// section's table with the key prefix "supervisor.".
[[nodiscard]] const ConfigSchema<core::SupervisorConfig>& supervisor_schema(SupervisorKeys which);

// `defaults` with the keys of `root`'s [supervisor] section applied (`root`: the whole file).
// Throws ConfigError naming every bad key at once.
[[nodiscard]] core::SupervisorConfig parse_supervisor_config(const toml::table& root, std::string_view source,
                                                             core::SupervisorConfig defaults, SupervisorKeys which);

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
