// Subcommands of the pmsm-thermal command-line tool. Each registers itself on the app and
// reports its exit status through `exit_code` when it runs.
#pragma once

#include <CLI/CLI.hpp>

namespace pmsm::app {

void register_budget_command(CLI::App& app, int& exit_code);
void register_losses_command(CLI::App& app, int& exit_code);
void register_simulate_command(CLI::App& app, int& exit_code);
void register_config_keys_command(CLI::App& app, int& exit_code);
void register_decode_command(CLI::App& app, int& exit_code);
void register_command_command(CLI::App& app, int& exit_code);
void register_monitor_command(CLI::App& app, int& exit_code);
void register_dbc_command(CLI::App& app, int& exit_code);

}  // namespace pmsm::app
