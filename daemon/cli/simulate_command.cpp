// `pmsm-thermal simulate SCENARIO.toml`: closes the loop in-process (controller + scheduler +
// estimator + plant library), lockstep and faster than real time, and reports the figures.
#include <cstdio>
#include <memory>
#include <string>

#include "../sim/runner.hpp"
#include "commands.hpp"
#include "pmsm/plant/config.hpp"

namespace pmsm::app {
namespace {

struct SimulateOptions {
  std::string scenario_path;
  bool json = false;
  std::string csv_path;
  std::string plot_path;
  bool quiet = false;
  bool events = false;
};

int run_simulate(const SimulateOptions& o) {
  Scenario scenario;
  try {
    scenario = load_scenario(o.scenario_path);
  } catch (const ConfigError& e) {
    std::fprintf(stderr, "simulate: %s\n", e.what());
    return 2;
  } catch (const plant::ConfigError& e) {
    std::fprintf(stderr, "simulate: %s\n", e.what());
    return 2;
  }
  RunOptions run;
  run.progress = !o.quiet;
  run.log_events = o.events;
  const SimulationResult result = run_scenario(scenario, run);
  int status = 0;
  try {
    if (!o.csv_path.empty()) {
      write_series_csv(result, o.csv_path);
    }
    if (!o.plot_path.empty()) {
      write_plot(result, o.plot_path);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "simulate: %s\n", e.what());
    status = 3;
  }
  if (o.events) {
    std::printf("%s\n", estimates_text(result).c_str());
    for (const std::string& line : result.event_log) {
      std::printf("%s\n", line.c_str());
    }
  }
  std::printf("%s\n", o.json ? result_json(result).c_str() : result_text(result).c_str());
  return status;
}

}  // namespace

void register_simulate_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<SimulateOptions>();
  CLI::App* cmd = app.add_subcommand(
      "simulate", "Run a scenario in-process (controller + estimator + plant, lockstep) and report its accuracy");
  cmd->add_option("scenario", options->scenario_path, "scenario file (TOML; see docs/scenarios.md)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_flag("--json", options->json, "print one JSON object with the figures");
  cmd->add_option("--csv", options->csv_path, "write the time series as CSV");
  cmd->add_option("--plot", options->plot_path, "draw true vs estimated temperatures as PNG (needs gnuplot)");
  cmd->add_flag("--quiet", options->quiet, "no progress line on a terminal");
  cmd->add_flag("--events", options->events, "list every published estimate with the truth and diagnostics");
  cmd->callback([options, &exit_code] { exit_code = run_simulate(*options); });
}

}  // namespace pmsm::app
