// pmsm-plant: the plant emulator as a process on a CAN bus (DESIGN §5). It sends the
// sensor samples, applies the inverter commands, and publishes the ground truth and its
// own status; see docs/plant.md, "The pmsm-plant process", and docs/hil.md.
//
//   pmsm-plant --config FILE.toml [--iface vcan0] [--node 0] [--mode lockstep|realtime]
//              [--truth-period-ms 100] [--command-timeout-ms 5] [--duration-s S] [--check]
//              [--accelerated-calibration]
//
// Exit status: 0 after a clean stop (duration reached, SIGINT, SIGTERM or SIGHUP) or a passing
// --check; 1 when the bus cannot be opened (no CAN in the kernel, no such interface, no CAN
// FD); 2 for a bad configuration (also a model that diverged while running: its state stopped
// being a number) and for a bad command line (the message names the flag).
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <string_view>
#include <utility>
#include <exception>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "cli_validators.hpp"
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/signals.hpp"
#include "pmsm/hal/socketcan.hpp"
#include "pmsm/plant/config.hpp"
#include "process/log.hpp"
#include "process/plant_node.hpp"

namespace {

using namespace std::chrono_literals;
namespace protocol = pmsm::hal::protocol;
using pmsm::plant::PlantNodeStats;

constexpr int kExitBus = 1;
constexpr int kExitConfig = 2;

struct Options {
  std::string config_path;
  std::string iface = "vcan0";
  int node = 0;
  std::string mode = "lockstep";
  double truth_period_ms = 100.0;
  double command_timeout_ms = 5.0;
  std::optional<double> duration_s;
  double resend_interval_ms = 50.0;
  int rt_priority = 0;
  std::string log_level = "info";
  bool check = false;
  bool accelerated_calibration = false;
};

std::string rejected_breakdown(const PlantNodeStats& now, const PlantNodeStats* before) {
  std::string text;
  for (std::size_t i = 1; i < now.rejected.size(); ++i) {
    const std::uint64_t n = now.rejected[i] - (before != nullptr ? before->rejected[i] : 0U);
    if (n != 0U) {
      text += fmt::format("{}{} {}", text.empty() ? "" : ", ",
                          protocol::to_string(static_cast<protocol::DecodeStatus>(i)), n);
    }
  }
  return text.empty() ? "none" : text;
}

// The non-real-time side: turns the node's counters into log lines, at most one line per
// topic per second (so a flood of bad frames cannot flood the journal), and only when
// something changed.
class Monitor {
 public:
  Monitor(const pmsm::plant::PlantNode& node, const Options& options, pmsm::plant::RunMode mode)
      : node_(node),
        iface_(options.iface),
        mode_(mode),
        command_timeout_ms_(options.command_timeout_ms),
        resend_interval_ms_(options.resend_interval_ms),
        thread_([this] { run(); }) {}
  ~Monitor() { stop(); }
  Monitor(const Monitor&) = delete;
  Monitor& operator=(const Monitor&) = delete;

  void stop() {
    {
      const std::lock_guard lock(mutex_);
      stopping_ = true;
    }
    wake_.notify_all();
    if (thread_.joinable()) {
      thread_.join();
    }
    report(node_.stats());  // whatever happened in the last second
  }

 private:
  void run() {
    std::unique_lock lock(mutex_);
    while (!wake_.wait_for(lock, 1s, [this] { return stopping_; })) {
      lock.unlock();
      report(node_.stats());
      lock.lock();
    }
  }

  void report(const PlantNodeStats& s) {
    const PlantNodeStats& p = last_;
    if (s.interface_down && !p.interface_down) {
      spdlog::error("CAN interface '{}' is down or gone: the plant stands still; checking every 200 ms and "
                    "reopening it when it is back", iface_);
    } else if (!s.interface_down && p.interface_down) {
      spdlog::info("CAN interface '{}' is back: socket reopened, running again", iface_);
    } else if (!s.interface_down && s.reopens != p.reopens) {
      // Lost and back between two reports.
      spdlog::warn("CAN interface '{}' was down or gone for a moment and is back: socket reopened, running "
                   "again ({} time(s) so far)", iface_, s.reopens);
    }
    if (s.rejected_total() != p.rejected_total()) {
      spdlog::warn("rejected {} frame(s) since the last report: {}", s.rejected_total() - p.rejected_total(),
                   rejected_breakdown(s, &p));
    }
    const std::uint64_t odd = s.stale_commands + s.duplicate_commands + s.future_commands;
    const std::uint64_t odd_before = p.stale_commands + p.duplicate_commands + p.future_commands;
    if (odd != odd_before && mode_ == pmsm::plant::RunMode::kLockstep) {
      spdlog::info("ignored {} INVERTER_COMMAND(s) with an unexpected sequence since the last report "
                   "(stale {}, duplicate {}, ahead {})",
                   odd - odd_before, s.stale_commands - p.stale_commands, s.duplicate_commands - p.duplicate_commands,
                   s.future_commands - p.future_commands);
    }
    if (s.waiting_for_controller != p.waiting_for_controller) {
      if (s.waiting_for_controller) {
        spdlog::info("waiting for a controller: sample {} not answered; re-sending it every {} ms", s.periods,
                     resend_interval_ms_);
      } else {
        spdlog::info("controller locked on (period {} at this report)", s.periods);
      }
    }
    const std::uint64_t new_timeouts = s.command_timeouts - p.command_timeouts;
    if (s.command_timeout_tripped && (new_timeouts != 0U || !p.command_timeout_tripped)) {
      spdlog::warn("command timeout: no valid, fresh INVERTER_COMMAND within {} ms: output disabled (safe torque "
                   "off); {} timeout(s) so far",
                   command_timeout_ms_, s.command_timeouts);
    } else if (!s.command_timeout_tripped && new_timeouts != 0U) {
      spdlog::warn("{} command timeout(s) since the last report (output disabled meanwhile); commands are "
                   "arriving again and the output follows them",
                   new_timeouts);
    } else if (!s.command_timeout_tripped && p.command_timeout_tripped) {
      spdlog::info("inverter commands are arriving again: the output follows them");
    }
    // A start is counted; an end is the flag going down. Both may fall inside one report.
    if (s.calibrations_followed != p.calibrations_followed) {
      spdlog::info("the controller calibrates: thermal time at real time until it is done (calibration {})",
                   s.calibrations_followed);
    }
    if (!s.calibration_real_time && (p.calibration_real_time || s.calibrations_followed != p.calibrations_followed)) {
      spdlog::info("the controller's calibration is over: thermal time accelerated again ({} calibration(s) "
                   "followed)", s.calibrations_followed);
    }
    if (s.tx_dropped != p.tx_dropped) {
      spdlog::warn("dropped {} frame(s) since the last report: the device queue stayed full (ENOBUFS)",
                   s.tx_dropped - p.tx_dropped);
    }
    if (s.tx_failures != p.tx_failures || s.rx_errors != p.rx_errors) {
      spdlog::warn("CAN I/O errors since the last report: {} failed send(s), {} failed read(s)",
                   s.tx_failures - p.tx_failures, s.rx_errors - p.rx_errors);
    }
    // Overruns are expected on a loaded or virtual machine; say so at most every 10 s.
    if (s.deadline_misses != overruns_reported_ &&
        (overruns_reported_ == 0 || ++seconds_since_overrun_report_ >= 10)) {
      spdlog::warn("real time: {} deadline miss(es) so far, {} period(s) skipped (simulated time behind the "
                   "wall clock), worst wake-up lateness {:.0f} us",
                   s.deadline_misses, s.missed_periods, static_cast<double>(s.max_lateness_ns) * 1e-3);
      overruns_reported_ = s.deadline_misses;
      seconds_since_overrun_report_ = 0;
    }
    last_ = s;
  }

  const pmsm::plant::PlantNode& node_;
  std::string iface_;
  pmsm::plant::RunMode mode_;
  double command_timeout_ms_;
  double resend_interval_ms_;
  PlantNodeStats last_{};
  std::uint64_t overruns_reported_ = 0;
  int seconds_since_overrun_report_ = 0;
  std::mutex mutex_;
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread thread_;  // last: started after everything it uses
};

std::string summary_line(const PlantNodeStats& s, double wall_s, const char* why) {
  return fmt::format(
      "stopped ({}): periods {} ({:.3f} s simulated in {:.2f} s, {:.0f} periods/s), commands applied {}, "
      "late {}, missing {}, stale {}, duplicate {}, ahead {}, command timeouts {}, sample re-sends {}, "
      "rejected frames {} ({}), tx dropped (ENOBUFS) {}, tx failures {}, rx errors {}, overruns {} "
      "({} periods skipped), interface losses {}",
      why, s.periods, s.simulated_time_s, wall_s, wall_s > 0.0 ? static_cast<double>(s.periods) / wall_s : 0.0,
      s.commands_applied, s.late_commands, s.missing_commands, s.stale_commands, s.duplicate_commands,
      s.future_commands, s.command_timeouts, s.sample_resends, s.rejected_total(), rejected_breakdown(s, nullptr),
      s.tx_dropped, s.tx_failures, s.rx_errors, s.deadline_misses, s.missed_periods, s.reopens);
}

void setup_realtime(int priority) {
  // Both are optional for an emulator: warn and run anyway (a development machine, CI).
  if (const pmsm::hal::Status s = pmsm::hal::prepare_memory_for_realtime(); !s.ok()) {
    spdlog::warn("{}", s.message());
  }
  pmsm::hal::prefault_stack();
  if (priority > 0) {
    if (const pmsm::hal::Status s = pmsm::hal::set_realtime_priority(priority); !s.ok()) {
      spdlog::warn("{}", s.message());
    }
  }
}

int run(const Options& o) {
  auto logger = pmsm::plant::make_process_logger("pmsm-plant", o.log_level);

  pmsm::plant::PlantConfig config;
  try {
    config = pmsm::plant::load_plant_config(o.config_path);
  } catch (const pmsm::plant::ConfigError& e) {
    spdlog::error("bad configuration: {}", e.what());
    return kExitConfig;
  }
  pmsm::plant::PlantNodeOptions node_options;
  node_options.node = static_cast<protocol::NodeId>(o.node);
  node_options.mode = o.mode == "realtime" ? pmsm::plant::RunMode::kRealtime : pmsm::plant::RunMode::kLockstep;
  node_options.truth_period = std::chrono::nanoseconds{static_cast<std::int64_t>(o.truth_period_ms * 1e6)};
  node_options.command_timeout = std::chrono::nanoseconds{static_cast<std::int64_t>(o.command_timeout_ms * 1e6)};
  node_options.resend_interval = std::chrono::nanoseconds{static_cast<std::int64_t>(o.resend_interval_ms * 1e6)};
  node_options.duration_s = o.duration_s;
  if (o.accelerated_calibration && config.thermal.acceleration == 1.0) {
    // The flag keeps an acceleration through a calibration; at 1 there is none to keep.
    spdlog::error("--accelerated-calibration does nothing with thermal.acceleration = 1 ({}): leave it out, or set "
                  "thermal.acceleration",
                  o.config_path);
    return kExitConfig;
  }
  node_options.follow_calibration = config.thermal.acceleration != 1.0 && !o.accelerated_calibration;
  if (o.check) {
    // The node publishes truth every whole number of PWM periods, at least one: what it will
    // do, not the flag as given.
    const double pwm_period_s = 1.0 / config.inverter.pwm_frequency_Hz;
    const double truth_ms =
        static_cast<double>(pmsm::plant::truth_every_periods(node_options.truth_period, pwm_period_s)) * pwm_period_s * 1e3;
    std::printf("%s: OK (PWM %.0f Hz, %s mode, node %d, truth every %g ms%s)\n", o.config_path.c_str(),
                config.inverter.pwm_frequency_Hz, o.mode.c_str(), o.node, truth_ms,
                std::abs(truth_ms - o.truth_period_ms) > 1e-9 * truth_ms ? ", --truth-period-ms rounded to whole PWM periods" : "");
    return 0;
  }

  // Kernel filters: only this node's INVERTER_COMMAND frames wake the plant (and, to follow
  // its calibrations, its THERMAL_ESTIMATE).
  pmsm::hal::SocketCanConfig bus_config;
  bus_config.interface = o.iface;
  bus_config.fd = true;  // SENSOR_SAMPLE and INVERTER_COMMAND are CAN FD frames
  bus_config.filters = pmsm::plant::plant_receive_filters(node_options);
  pmsm::hal::Status open_error;
  std::unique_ptr<pmsm::hal::SocketCanBus> bus = pmsm::hal::SocketCanBus::open(bus_config, open_error);
  if (!bus) {
    spdlog::error("cannot open the CAN bus: {}", open_error.message());
    return kExitBus;
  }

  std::optional<pmsm::plant::PlantNode> node;
  try {
    node.emplace(config, *bus, node_options);
  } catch (const std::exception& e) {  // ConfigError from the plant, invalid_argument from the options
    spdlog::error("bad configuration: {}", e.what());
    return kExitConfig;
  }

  spdlog::info("{} mode on '{}', node {}, config {} (PWM {:.0f} Hz), truth and status every {} period(s) of "
               "simulated time{}{}",
               to_string(node_options.mode), o.iface, o.node, o.config_path, config.inverter.pwm_frequency_Hz,
               node->truth_every_periods(),
               node_options.mode == pmsm::plant::RunMode::kRealtime
                   ? fmt::format(", command timeout {} ms", o.command_timeout_ms)
                   : std::string{},
               o.duration_s ? fmt::format(", stopping after {} s simulated", *o.duration_s) : std::string{});

  if (const pmsm::hal::Status s = pmsm::hal::install_stop_signals(); !s.ok()) {
    spdlog::warn("{}; stop with SIGKILL", s.message());
  }
  const std::int64_t t0_ns = pmsm::hal::monotonic_ns();
  pmsm::plant::StopReason reason = pmsm::plant::StopReason::kStopRequested;
  {
    // The monitor thread starts before this thread raises its priority, so it keeps the
    // normal policy (threads inherit the creator's scheduling).
    Monitor monitor(*node, o, node_options.mode);
    if (node_options.mode == pmsm::plant::RunMode::kRealtime) {
      setup_realtime(o.rt_priority);
    }
    reason = node->run(pmsm::hal::stop_requested());
    monitor.stop();
  }
  const double wall_s = static_cast<double>(pmsm::hal::monotonic_ns() - t0_ns) * 1e-9;
  if (reason == pmsm::plant::StopReason::kDiverged) {
    spdlog::error("the model diverged at {:.6g} s of simulated time (its currents or speed are no longer numbers): a "
                  "machine its integration cannot follow; check [motor] and simulation.substeps. Stopped",
                  node->plant().diverged_at_s());
  }
  spdlog::info("{}", summary_line(node->stats(), wall_s,
                                  reason == pmsm::plant::StopReason::kDuration   ? "duration reached"
                                  : reason == pmsm::plant::StopReason::kDiverged ? "model diverged"
                                                                                 : "signal"));
  logger->flush();
  return reason == pmsm::plant::StopReason::kDiverged ? kExitConfig : 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"pmsm-plant: the PMSM, inverter, thermal network and sensors on a CAN bus (lockstep or real time)"};
  Options o;
  app.set_version_flag("--version", std::string("pmsm-plant ") + PMSM_VERSION);
  app.add_option("--config", o.config_path, "plant configuration (TOML), e.g. /usr/share/pmsm-thermal/plant-profiles/reference.toml (installed) or plant-emulator/profiles/reference.toml (the source tree)")
      ->required()
      ->check(pmsm::cli::file_name());
  app.add_option("--iface", o.iface, "CAN interface (CAN FD, MTU 72)")
      ->capture_default_str()
      ->check(pmsm::cli::text_rule(pmsm::hal::can_interface_name_problem, "NAME"));
  app.add_option("--node", o.node, "node id 0..15 (added to every CAN ID)")->check(pmsm::cli::integer_in_range(0, 15))
      ->capture_default_str();
  app.add_option("--mode", o.mode, "lockstep: one period per command (the plant is deterministic; the daemon's wall-clock timeouts need not be); realtime: own clock")
      ->check(CLI::IsMember({"lockstep", "realtime"}))->capture_default_str();
  app.add_option("--truth-period-ms", o.truth_period_ms,
                 "simulated time between TRUTH_THERMAL/TRUTH_ELECTRICAL/PLANT_STATUS publications, ms")
      ->check(pmsm::cli::number_in_range(0.001, 3.6e6))->capture_default_str();
  app.add_option("--command-timeout-ms", o.command_timeout_ms,
                 "realtime: output off after this long without a valid command, ms")
      ->check(pmsm::cli::number_in_range(0.001, 3.6e6))->capture_default_str();
  app.add_option("--duration-s", o.duration_s, "stop after this much simulated time, s (default: run until a signal)")
      ->check(pmsm::cli::number_in_range(0.0, 1.0e9));
  app.add_option("--resend-interval-ms", o.resend_interval_ms,
                 "lockstep: re-send an unanswered sample after this long (wall clock), ms")
      ->check(pmsm::cli::number_in_range(0.1, 60000.0))->capture_default_str();
  app.add_option("--rt-priority", o.rt_priority, "realtime: SCHED_FIFO priority 1..99 for the plant thread (0: leave)")
      ->check(pmsm::cli::integer_in_range(0, 99))->capture_default_str();
  app.add_option("--log-level", o.log_level, "trace, debug, info, warning (or warn), error: as pmsm-thermald takes them")
      ->check(CLI::IsMember({"trace", "debug", "info", "warning", "warn", "error"}))->capture_default_str();
  app.add_flag("--check", o.check, "validate the configuration and exit (0: valid)");
  app.add_flag("--accelerated-calibration", o.accelerated_calibration,
               "with thermal.acceleration other than 1, keep it while the node calibrates (default: real thermal "
               "time while THERMAL_ESTIMATE says Calibrating, as pmsm-thermald's model runs)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; a bad command line is a configuration error (2), not one
    // of CLI11's own codes.
    return pmsm::cli::exit_on_parse_error(app, e, kExitConfig, "pmsm-plant", kExitBus);
  }
  // A flag of the other mode would do nothing: said, not ignored.
  for (const auto& [flag, mode] : {std::pair<const char*, const char*>{"--command-timeout-ms", "realtime"},
                                   {"--rt-priority", "realtime"},
                                   {"--resend-interval-ms", "lockstep"}}) {
    const bool left_alone = std::string_view(flag) == "--rt-priority" && o.rt_priority == 0;  // 0: "leave it"
    if (app.count(flag) > 0U && o.mode != mode && !left_alone) {
      std::fprintf(stderr, "pmsm-plant: %s applies to --mode %s only (this run is --mode %s)\n", flag, mode,
                   o.mode.c_str());
      return kExitConfig;
    }
  }
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pmsm-plant: %s\n", e.what());
    return kExitBus;
  }
}
