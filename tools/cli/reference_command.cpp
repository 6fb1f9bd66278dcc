// `pmsm-thermal config-keys`: the reference tables of every configuration key, generated from
// the same schema that parses the files (docs/configuration.md, docs/scenarios.md and
// docs/plant.md embed them; a test keeps those files current).
#include <cstdio>
#include <memory>
#include <string>

#include "config_schema.hpp"
#include "controller_config.hpp"
#include "pmsm/plant/config.hpp"
#include "standard_output.hpp"
#include "scenario.hpp"
#include "commands.hpp"

namespace pmsm::app {

void register_config_keys_command(CLI::App& app, int& exit_code) {
  auto which = std::make_shared<std::string>("controller");
  CLI::App* cmd = app.add_subcommand("config-keys", "Print the reference table of configuration keys (Markdown)");
  cmd->add_option("which", *which, "controller (pmsm-thermald and [controller] of scenarios), scenario or plant")
      ->check(CLI::IsMember({"controller", "scenario", "plant"}))
      ->capture_default_str();
  cmd->callback([which, &exit_code] {
    // In one go: a full disk is named with the write's own reason (standard_output.hpp).
    (void)cli::write_standard_output(*which == "scenario" ? scenario_keys_markdown()
                                     : *which == "plant"  ? plant::plant_config_reference_markdown()
                                                          : controller_schema().markdown(default_controller_config()));
    exit_code = 0;
  });
}

}  // namespace pmsm::app
