// `pmsm-thermal simulate SCENARIO.toml...`: closes the loop in-process (controller +
// scheduler + estimator + plant library), lockstep and faster than real time, and reports
// the figures. Several scenarios make a side-by-side table (--markdown), the accuracy
// benchmark of docs/accuracy.md.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "cli_validators.hpp"
#include "config_types.hpp"
#include "calibration_file.hpp"
#include "runner.hpp"
#include "text_file.hpp"
#include "commands.hpp"
#include "pmsm/plant/config.hpp"

namespace pmsm::app {
namespace {

struct SimulateOptions {
  std::vector<std::string> scenario_paths;
  bool json = false;
  bool markdown = false;
  std::string csv_path;
  std::string plot_path;
  std::string plot_dir;
  bool quiet = false;
  bool events = false;
  int jobs = 1;
};

// What one scenario prints, kept until its turn: with -j, scenarios finish out of order but
// are reported in the order given.
struct Report {
  std::string out;    // stdout
  std::string err;    // stderr
  std::string row;    // its Markdown row
  int status = 0;
};

std::string cell(double value, bool valid, const char* format = "{:.2f}") {
  return valid && std::isfinite(value) ? fmt::format(fmt::runtime(format), value) : std::string("–");
}

std::string markdown_header() {
  return "| scenario | method | winding RMS (°C) | winding max (°C) | winding mean (°C) | ±2σ coverage (%) | Rs RMS (mΩ) | "
         "magnet RMS (°C) | estimates | pairs accepted / rejected | speed disturbance (%) | torque disturbance (% rated) | "
         "injection loss (W) | sim / wall (s) |\n"
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
}

std::string markdown_row(const SimulationResult& r, const std::string& file) {
  std::uint32_t rejected = 0;
  for (std::size_t k = 1; k < r.pairs.size(); ++k) {
    rejected += r.pairs[k];
  }
  const bool w = r.winding_error_samples > 0;
  // A calibration that failed makes the row the figures of the calibration in use before it
  // (the configured keys): said in the row, not left to be found.
  const std::string failed = r.calibration_failure == core::CalibrationFailure::kNone
                                 ? std::string()
                                 : fmt::format(" — calibration failed: {}", core::calibration_failure_name(r.calibration_failure));
  // A trip likewise: the figures after it are those of a drive that is off.
  const SimulationResult::FaultSeen* trip = r.first_fault();
  const std::string tripped =
      trip == nullptr ? std::string() : fmt::format(" — tripped: {} at {:.1f} s", core::to_string(r.fault_code(*trip)), trip->first_s);
  // The calibration's bridge sweep and rotor-angle check likewise, when one ran and did not
  // measure: the calibration then stands on the configured Vx, band or angle (the JSON has why).
  std::string checks;
  if (r.inverter_sweep.outcome != core::InverterSweepOutcome::kNone &&
      r.inverter_sweep.outcome != core::InverterSweepOutcome::kMeasured) {
    checks += fmt::format(" — bridge sweep: {}", core::to_string(r.inverter_sweep.outcome));
  }
  if (r.angle_check.outcome != core::AngleCheckOutcome::kNone && r.angle_check.outcome != core::AngleCheckOutcome::kMeasured) {
    checks += fmt::format(" — angle check: {}", core::to_string(r.angle_check.outcome));
  }
  return fmt::format("| {} (`{}`){}{}{} | {} | {} | {} | {} | {} | {} | {} | {} | {} / {} | {} | {} | {:.1f} | {:.0f} / {:.1f} |\n",
                     common::markdown_cell(r.scenario), common::markdown_cell(file), failed, tripped, checks, r.method, cell(r.winding_error_rms_C, w), cell(r.winding_error_max_C, w),
                     cell(r.winding_error_mean_C, w, "{:+.2f}"), cell(100.0 * r.coverage_2sigma, w, "{:.0f}"),
                     cell(r.rs_error_rms_mohm, r.estimates_published() > 0 && std::isfinite(r.rs_error_rms_mohm)), cell(r.magnet_error_rms_C, r.magnet_error_samples > 0),
                     r.estimates_accepted, r.pairs[0], rejected, cell(r.speed_disturbance_pct, r.disturbance_measured, "{:.3f}"),
                     cell(r.torque_disturbance_pct, r.disturbance_measured), r.injection_loss_W, r.sim_time_s, r.wall_time_s);
}

Report run_one(const std::string& path, const Scenario& scenario, const SimulateOptions& o) {
  Report r;
  for (const std::string& w : configuration_warnings(scenario.controller)) {
    r.err += fmt::format("simulate: {}: warning: {}\n", path, w);
  }
  RunOptions run;
  run.progress = !o.quiet && o.jobs == 1;
  run.log_events = o.events;
  // Memory follows the output asked for, not the simulated time: the series only for a CSV or a
  // plot, the estimates only for --events or a plot; the figures are streamed.
  const bool plots = !o.plot_path.empty() || !o.plot_dir.empty();
  run.keep_series = !o.csv_path.empty() || plots;
  run.keep_estimates = o.events || plots;
  SimulationResult result;
  try {
    result = run_scenario(scenario, run);
  } catch (const CalibrationFileError& e) {
    r.err += fmt::format("simulate: the stored calibration cannot be used: {}\n", e.what());
    r.status = 2;
    return r;
  } catch (const PlantDivergedError& e) {
    r.err += fmt::format("simulate: {}: {}; no figures\n", path, e.what());
    r.status = 2;
    return r;
  }
  int& status = r.status;
  if (result.calibration_running_at_end) {
    r.err += fmt::format("simulate: {}: the calibration had not finished when the run ended; the figures count from "
                         "a calibration that is not there (run longer, or start it earlier)\n",
                         path);
  }
  if (result.calibration_failure == core::CalibrationFailure::kTimeout) {
    // Why it timed out: its pairs' outcomes (a load, a speed ramp, the voltage limit).
    r.err += fmt::format("simulate: {}: the calibration failed (timeout at {:.2f} s{}: {}); the figures are those of the "
                         "calibration in use before it\n",
                         path, result.calibration_failure_time_s,
                         calibration_pairs_text(result.estimator, result.calibration_failure_pairs,
                                                result.calibration_failure_aborts),
                         calibration_timeout_advice(result.estimator));
  } else if (result.calibration_failure == core::CalibrationFailure::kRsOutsideWindow) {
    r.err += fmt::format("simulate: {}: the calibration failed (rs_outside_window at {:.2f} s: {}); the figures are those "
                         "of the calibration in use before it\n",
                         path, result.calibration_failure_time_s, result.calibration_failure_detail);
  } else if (result.calibration_failure != core::CalibrationFailure::kNone) {
    r.err += fmt::format("simulate: {}: the calibration failed ({} at {:.2f} s); the figures are those of the "
                         "calibration in use before it\n",
                         path, core::calibration_failure_name(result.calibration_failure), result.calibration_failure_time_s);
  }
  if (const std::string advice = pair_rejection_advice(result.pairs, scenario.controller.drive); !advice.empty()) {
    r.err += fmt::format("simulate: {}: {}\n", path, advice);
  }
  if (const SimulationResult::FaultSeen* trip = result.first_fault(); trip != nullptr) {
    r.err += fmt::format("simulate: {}: the drive tripped ({} at {:.3f} s) and stayed off; the figures include the run after it\n",
                         path, core::to_string(result.fault_code(*trip)), trip->first_s);
  }
  if (!result.calibration_file_error.empty()) {
    // The run is reported in full; only the file kept its previous content.
    r.err += fmt::format("simulate: the calibration was not stored: {}\n", result.calibration_file_error);
    status = 3;
  }
  const std::string stem = std::filesystem::path(path).stem().string();
  try {
    if (!o.csv_path.empty()) {
      write_series_csv(result, o.csv_path);
    }
    if (!o.plot_path.empty()) {
      write_plot(result, o.plot_path);
    }
    if (!o.plot_dir.empty()) {
      std::error_code ec;
      std::filesystem::create_directories(o.plot_dir, ec);
      if (ec) {
        throw std::runtime_error(fmt::format("--plot-dir {}: cannot create the directory ({})", o.plot_dir, ec.message()));
      }
      write_plot(result, (std::filesystem::path(o.plot_dir) / (stem + ".png")).string());
    }
  } catch (const std::exception& e) {
    r.err += fmt::format("simulate: {}\n", e.what());
    status = 3;
  }
  if (o.events) {
    r.out += estimates_text(result) + "\n";
    for (const std::string& line : result.event_log) {
      r.out += line + "\n";
    }
  }
  if (o.markdown) {
    r.row = markdown_row(result, std::filesystem::path(path).filename().string());
  } else {
    r.out += (o.json ? result_json(result) : result_text(result)) + "\n";
  }
  return r;
}

int run_simulate(const SimulateOptions& o) {
  if (o.scenario_paths.size() > 1 && (!o.csv_path.empty() || !o.plot_path.empty())) {
    std::fprintf(stderr, "simulate: --csv and --plot take one scenario; use --plot-dir for several\n");
    return 2;
  }
  // Every scenario is loaded before any runs: one that cannot be used is named (all of them,
  // each with its file, line and key) and nothing runs, as docs/scenarios.md says.
  const std::size_t n = o.scenario_paths.size();
  std::vector<Scenario> scenarios(n);
  bool unusable = false;
  for (std::size_t k = 0; k < n; ++k) {
    try {
      scenarios[k] = load_scenario(o.scenario_paths[k]);
    } catch (const ConfigError& e) {  // the plant's, the controller's and the scenario's alike
      std::fprintf(stderr, "simulate: %s\n", e.what());
      unusable = true;
    } catch (const std::exception& e) {  // not one of the documented failures: say so
      std::fprintf(stderr, "simulate: %s: %s\n", o.scenario_paths[k].c_str(), e.what());
      unusable = true;
    }
  }
  if (unusable) {
    return 2;
  }
  // An output written over an input (the scenario, a base, a CSV, the plant profile, the stored
  // calibration or thermal state) would replace it with a CSV or a plot; two outputs on one
  // file would keep only the last.
  if (!o.csv_path.empty() && !o.plot_path.empty() && common::same_file(o.csv_path, o.plot_path)) {
    std::fprintf(stderr, "simulate: --csv and --plot name the same file %s: one would replace the other\n",
                 o.csv_path.c_str());
    return 2;
  }
  // A time series is kept whole for --csv and --plot (SeriesRow, about 200 bytes a row): one
  // beyond ten million rows (2 GB) is refused before it runs, not as std::bad_alloc after.
  if (!o.csv_path.empty() || !o.plot_path.empty() || !o.plot_dir.empty()) {
    constexpr double kMaxSeriesRows = 1e7;
    for (std::size_t k = 0; k < n; ++k) {
      const ScenarioConfig& sc = scenarios[k].scenario;
      const double rows = sc.duration_s / std::max(sc.log_period_s, scenarios[k].controller.drive.period_s);
      if (rows > kMaxSeriesRows) {
        std::fprintf(stderr,
                     "simulate: %s: scenario.duration_s / metrics.log_period_s = %.3g rows of time series for --csv or "
                     "--plot, more than %.0f (about 2 GB): raise metrics.log_period_s or leave the series out\n",
                     o.scenario_paths[k].c_str(), rows, kMaxSeriesRows);
        return 2;
      }
    }
  }
  // An output that cannot be written is said before the run, not after it (a long scenario ran
  // to its end and then said "cannot write adir"): 3, as an output that fails after the run.
  if (!o.plot_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(o.plot_dir, ec);
    if (ec) {
      std::fprintf(stderr, "simulate: --plot-dir %s: cannot create the directory (%s)\n", o.plot_dir.c_str(),
                   ec.message().c_str());
      return 3;
    }
  }
  for (std::size_t k = 0; k < n; ++k) {
    const std::string plot_in_dir =
        o.plot_dir.empty() ? std::string()
                           : (std::filesystem::path(o.plot_dir) / (std::filesystem::path(o.scenario_paths[k]).stem().string() + ".png"))
                                 .string();
    for (const auto& [option, output] : {std::pair<const char*, const std::string&>{"--csv", o.csv_path},
                                         {"--plot", o.plot_path},
                                         {"--plot-dir", plot_in_dir}}) {
      if (output.empty()) {
        continue;
      }
      for (const std::filesystem::path& input : scenarios[k].files) {
        if (common::same_file(output, input)) {
          const bool itself = &input == &scenarios[k].files.front();
          std::fprintf(stderr, "simulate: %s %s would write over %s%s: refusing\n", option, output.c_str(),
                       itself ? "the scenario " : "", itself ? o.scenario_paths[k].c_str()
                                                             : (input.string() + ", which the scenario " + o.scenario_paths[k] +
                                                                " reads or keeps its state in").c_str());
          return 2;
        }
      }
      if (const std::string problem = common::writable_file_problem(output); !problem.empty()) {
        std::fprintf(stderr, "simulate: %s %s: cannot write it (%s); nothing was run\n", option, output.c_str(),
                     problem.c_str());
        return 3;
      }
    }
  }
  // -j N: N scenarios at a time, each (with its own twin thread) independent of the others;
  // reports are printed in the order the scenarios were given, each as soon as it and those
  // before it are done.
  if (o.jobs > 1 && n > 1) {
    // Scenarios that store and load the same calibration or thermal-state file depend on their order: with
    // -j it would be a race.
    std::map<std::filesystem::path, std::string> owner;
    for (std::size_t k = 0; k < n; ++k) {
      const std::string& path = o.scenario_paths[k];
      const ControllerConfig& controller = scenarios[k].controller;
      for (const std::string* file_ptr : {&controller.calibration_file, &controller.thermal_state_file}) {
        const std::string& file = *file_ptr;
        if (file.empty()) {
          continue;
        }
        std::error_code ec;
        std::filesystem::path key = std::filesystem::weakly_canonical(file, ec);
        if (ec) {
          key = std::filesystem::path(file).lexically_normal();
        }
        const auto [it, inserted] = owner.emplace(key, path);
        if (!inserted && it->second != path) {
          std::fprintf(stderr,
                       "simulate: %s and %s both use the stored file %s: their order decides what each "
                       "loads; run them with -j 1\n",
                       it->second.c_str(), path.c_str(), key.c_str());
          return 2;
        }
      }
    }
  }
  std::vector<std::optional<Report>> reports(n);
  std::mutex mutex;
  std::condition_variable done;
  std::atomic<std::size_t> next{0};
  auto worker = [&] {
    for (std::size_t k = next++; k < n; k = next++) {
      Report r;
      try {
        r = run_one(o.scenario_paths[k], scenarios[k], o);
      } catch (const std::exception& e) {  // not one of the documented failures: say so, go on
        r.err = fmt::format("simulate: {}: {}\n", o.scenario_paths[k], e.what());
        r.status = 1;
      }
      const std::lock_guard<std::mutex> lock(mutex);
      reports[k] = std::move(r);
      done.notify_one();
    }
  };
  std::vector<std::thread> workers;
  const auto jobs = static_cast<std::size_t>(std::max(1, o.jobs));
  for (std::size_t w = 0; w < std::min(jobs, n); ++w) {
    workers.emplace_back(worker);
  }
  std::string table;
  int status = 0;
  for (std::size_t k = 0; k < n; ++k) {
    std::unique_lock<std::mutex> lock(mutex);
    done.wait(lock, [&] { return reports[k].has_value(); });
    const Report r = std::move(*reports[k]);
    lock.unlock();
    std::fputs(r.err.c_str(), stderr);
    std::fputs(r.out.c_str(), stdout);
    std::fflush(stdout);
    table += r.row;
    status = std::max(status, r.status);
  }
  for (std::thread& t : workers) {
    t.join();
  }
  if (o.markdown) {
    std::printf("%s%s", markdown_header().c_str(), table.c_str());
  }
  return status;
}

}  // namespace

void register_simulate_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<SimulateOptions>();
  CLI::App* cmd = app.add_subcommand(
      "simulate", "Run scenarios in-process (controller + estimator + plant, lockstep) and report their accuracy");
  cmd->add_option("scenario", options->scenario_paths, "scenario files (TOML; see docs/scenarios.md)")
      ->required();  // a missing file is the scenario's error (exit 2, docs/scenarios.md), not a usage error
  CLI::Option* json = cmd->add_flag("--json", options->json, "print one JSON object per scenario with the figures");
  cmd->add_flag("--markdown", options->markdown, "print one Markdown table, a row per scenario")->excludes(json);
  cmd->add_option("--csv", options->csv_path, "write the time series as CSV (one scenario)")->check(pmsm::cli::file_name());
  cmd->add_option("--plot", options->plot_path, "draw true vs estimated temperatures as PNG (one scenario; needs gnuplot)")
      ->check(pmsm::cli::file_name());
  cmd->add_option("--plot-dir", options->plot_dir, "draw a PNG per scenario into this directory, named after the file")
      ->check(pmsm::cli::file_name());
  cmd->add_flag("--quiet", options->quiet, "no progress line on a terminal");
  cmd->add_option("-j,--jobs", options->jobs, "run this many scenarios at a time (an injecting one also steps its twin, around its events, on a thread of its own)")
      ->check(pmsm::cli::integer_in_range(1, 256))->capture_default_str();
  cmd->add_flag("--events", options->events, "list every published estimate with the truth and diagnostics");
  cmd->callback([options, &exit_code] { exit_code = run_simulate(*options); });
}

}  // namespace pmsm::app
