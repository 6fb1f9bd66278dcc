// pmsm-thermald: the real-time drive daemon (one axis per process). See docs/daemon.md.
//
//   pmsm-thermald --config /etc/pmsm-thermal/axis1.toml [--check] [--keys] [--version]
//
// Start-up, in order, each step failing with one line that says what is wrong: the
// configuration, the stored calibration, the CAN sockets (with kernel filters for exactly
// the frames this node consumes), GPIO (gate enable requested inactive), memory locking, the
// RT thread (SCHED_FIFO and affinity; a warning where not permitted), then READY=1 to
// systemd (a no-op outside systemd). The main thread then feeds the watchdog while the RT
// loop's heartbeat advances, mirrors the gate enable to GPIO and watches the fault input.
//
// Exit status: 0 after a clean stop (SIGINT, SIGTERM, SIGHUP); 1 when the CAN interface does not
// exist (yet); 2 for a bad configuration or calibration file, an interface that exists and cannot
// be opened, or a GPIO chip or line that cannot be had (the unit does not restart on it:
// RestartPreventExitStatus=2). --check: 0 valid, 1 not.
#include <net/if.h>
#include <systemd/sd-daemon.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <future>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <utility>

#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/sinks/systemd_sink.h>
#include <spdlog/spdlog.h>

#include "calibration_file.hpp"
#include "cli_validators.hpp"
#include "standard_output.hpp"
#include "daemon_config.hpp"
#include "drive_loop.hpp"
#include "fault_watch.hpp"
#include "pmsm/hal/gpio.hpp"
#include "pmsm/hal/journal.hpp"
#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/record_drain.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/signals.hpp"
#include "pmsm/hal/socketcan.hpp"
#include "publisher.hpp"

#ifndef PMSM_VERSION
#define PMSM_VERSION "unknown"
#endif

namespace {

using namespace std::chrono_literals;
namespace protocol = pmsm::hal::protocol;
using pmsm::daemon::DaemonConfig;

constexpr int kExitIo = 1;
constexpr int kExitConfig = 2;
// systemd/pmsm-thermald@.service's LimitRTPRIO= (tests/unit/daemon_check.sh reads it there).
constexpr int kUnitMaxRtPriority = 90;

// An interface that does not exist (yet: a USB adapter, a .netdev that comes late) is worth
// waiting for: exit 1, which the unit restarts. One that exists and still cannot be opened (not
// a CAN interface, classic CAN only, no permission) is a configuration to fix: exit 2, which
// the unit does not restart (a non-CAN interface restarted it every second for good).
// A missing virtual bus is named with what makes one: on a fresh Debian 12 the package's
// 80-vcan0.netdev waits for a systemd-networkd that is not enabled, and the unit restarted the
// daemon every second saying only that vcan0 was missing.
int bus_open_failure(const char* what, const std::string& interface, const pmsm::hal::Status& error) {
  const bool exists = ::if_nametoindex(interface.c_str()) != 0;
  std::string hint;
  if (exists) {
    hint = " (the interface exists: a configuration to fix, not retried)";
  } else if (pmsm::daemon::is_virtual_interface(interface) && error.error_number() != EAFNOSUPPORT &&
             error.error_number() != EPROTONOSUPPORT) {
    // (Not on a kernel without CAN or can_raw, where the message says what to load.)
    hint = fmt::format(
        " (retried; a virtual bus is made {}by hand: ip link add {} type vcan && ip link set {} up)",
        interface == "vcan0" ? "by the package's 80-vcan0.netdev once systemd-networkd runs (Debian does not enable "
                               "it: systemctl enable --now systemd-networkd), or "
                             : "",
        interface, interface);
  }
  spdlog::error("{}: {}{}", what, error.message(), hint);
  return exists ? kExitConfig : kExitIo;
}

void setup_logging(const std::string& level) {
  // Where stderr is the journal's stream (a unit's default) log to the journal with priorities;
  // elsewhere to stderr, also from under systemd: a `--check` run from a service's shell wrote
  // its refusal to the journal and printed nothing (hal::stderr_is_journal).
  const bool journal = pmsm::hal::stderr_is_journal();
  std::shared_ptr<spdlog::logger> logger;
  if (journal) {
    logger = std::make_shared<spdlog::logger>("pmsm-thermald", std::make_shared<spdlog::sinks::systemd_sink_mt>("pmsm-thermald"));
    logger->set_pattern("%v");
  } else {
    logger = std::make_shared<spdlog::logger>("pmsm-thermald", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
    logger->set_pattern("%Y-%m-%d %H:%M:%S.%e pmsm-thermald %^%l%$: %v");
  }
  logger->set_level(spdlog::level::from_str(level));
  logger->flush_on(spdlog::level::info);
  spdlog::set_default_logger(logger);
}

// The RT thread's own set-up, reported back to the main thread for logging.
struct RtSetup {
  std::string priority_warning;
  std::string affinity_warning;
  bool priority_granted = false;
};

struct Options {
  std::string config_path;
  bool check = false;
  bool keys = false;
  std::string log_level = "info";
};

// The thermal state kept from before this start, if it can be used: a damaged, future or
// week-old file is not, nor one another axis wrote (`why` says so; empty when there is no file
// yet).
std::optional<pmsm::app::StoredThermalState> usable_thermal_state(const DaemonConfig& config, double& downtime_s,
                                                                  std::string& why) {
  const std::string& path = config.controller.thermal_state_file;
  std::error_code ec;
  why.clear();
  if (path.empty()) {
    return std::nullopt;
  }
  if (!std::filesystem::exists(path, ec)) {
    if (ec) {
      why = fmt::format("{}: cannot be looked at ({})", path, ec.message());  // e.g. a directory it may not enter
    }
    return std::nullopt;
  }
  try {
    pmsm::app::StoredThermalState s = pmsm::app::read_thermal_state_file(path);
    const double now = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
    downtime_s = now - s.saved_unix_s;
    if (!(downtime_s >= 0.0) || downtime_s > 7.0 * 86400.0) {
      why = fmt::format("{} is {:.0f} s old (clock changed?)", path, downtime_s);
      return std::nullopt;
    }
    // Another axis's winding is not this one's (two configurations naming one file: one copied
    // for a second axis). A file from before the axis was recorded is taken as this axis's.
    why = pmsm::app::other_axis_problem(path, s.axis, pmsm::daemon::stored_axis(config), "controller.thermal.state_file");
    if (!why.empty()) {
      return std::nullopt;
    }
    return s;
  } catch (const std::exception& e) {
    why = e.what();
    return std::nullopt;
  }
}

// A stored thermal state's learned blocks that are not used (a bad or missing value: each costs
// only itself; the temperatures are kept), said at the start or, `would`, by --check.
void warn_unused_thermal_blocks(const pmsm::app::StoredThermalState& s, bool would) {
  const char* const are_not = would ? "would not be" : "not";
  const char* const restart = would ? "would restart" : "restart";
  const char* const restarts = would ? "would restart" : "restarts";
  if (!s.loss_errors_ignored.empty()) {
    spdlog::warn("thermal state: the loss model's errors {} used ({}); they {} from the priors, the temperatures are "
                 "kept", are_not, s.loss_errors_ignored, restart);
  }
  if (!s.cooling_error_ignored.empty()) {
    spdlog::warn("thermal state: the cooling path's error {} used ({}); it {} from its prior, the temperatures are "
                 "kept", are_not, s.cooling_error_ignored, restarts);
  }
}

// The thermal state kept from before this start: cooled through the downtime by the model. A
// damaged, future or week-old file is not used (the filter then starts from the ambient
// sensor, as without one): it is a prediction, never worth refusing to start for.
void restore_thermal_state(const DaemonConfig& config, pmsm::daemon::DriveLoop& loop) {
  const std::string& path = config.controller.thermal_state_file;
  if (path.empty()) {
    return;
  }
  double downtime_s = 0.0;
  std::string why;
  const std::optional<pmsm::app::StoredThermalState> stored = usable_thermal_state(config, downtime_s, why);
  if (!stored) {
    if (why.empty()) {
      spdlog::info("thermal state: {} not there yet: the filter starts from the ambient sensor", path);
    } else {
      spdlog::warn("thermal state not used: {}; the filter starts from the ambient sensor", why);
    }
    return;
  }
  const pmsm::app::StoredThermalState& s = *stored;
  loop.restore_thermal_state(s.state, downtime_s, s.ambient_C);
  spdlog::info("thermal state restored from {}: winding {:.1f} +- {:.1f} C {:.0f} s ago, cooled towards the stored "
               "ambient {:.1f} C to {:.1f} +- {:.1f} C",
               path, s.state.winding_C, s.state.winding_std_C, downtime_s, s.ambient_C,
               loop.node().controller().thermal_state().winding_C, loop.node().controller().thermal_state().winding_std_C);
  if (s.state.has_loss_errors) {
    const pmsm::core::ThermalState kept = loop.node().controller().thermal_state();
    spdlog::info("thermal state: the loss model's learned errors kept: missing loss {:.1f} +- {:.1f} W, copper loss scale "
                 "{:+.3f} +- {:.3f} (after the downtime)",
                 kept.missing_loss_W, kept.missing_loss_std_W, kept.loss_scale_error, kept.loss_scale_std);
  }
  const pmsm::core::ThermalState restored = loop.node().controller().thermal_state();
  if (s.state.has_cooling_error && restored.has_cooling_error) {
    spdlog::info("thermal state: the cooling path's learned error kept: {:+.3f} +- {:.3f} of the model's conductance "
                 "(after the downtime)",
                 restored.cooling_scale_error, restored.cooling_scale_std);
  }
  warn_unused_thermal_blocks(s, false);
}

// Why the daemon could not write `path` (the calibration, the thermal state) when the time
// comes, or "": its directory must exist and be writable (systemd's StateDirectory= makes
// /var/lib/pmsm-thermal), and the path must not be a directory.
std::string unwritable_reason(const std::string& path) {
  std::error_code ec;
  const std::filesystem::path file(path);
  const std::filesystem::path dir = file.has_parent_path() ? file.parent_path() : std::filesystem::path(".");
  if (std::filesystem::is_directory(file, ec)) {
    return "it is a directory";
  }
  if (!std::filesystem::is_directory(dir, ec)) {
    return fmt::format("its directory {} does not exist", dir.string());
  }
  if (::access(dir.c_str(), W_OK) != 0) {
    return fmt::format("its directory {} is not writable ({})", dir.string(), std::strerror(errno));
  }
  return {};
}

int run(const Options& o) {
  setup_logging(o.log_level);
  DaemonConfig config;
  try {
    config = pmsm::daemon::load_daemon_config(o.config_path);
  } catch (const std::exception& e) {
    spdlog::error("bad configuration: {}", e.what());
    return o.check ? 1 : kExitConfig;
  }
  const pmsm::daemon::BusLoad load = pmsm::daemon::bus_load(config);
  const std::string budget = fmt::format(
      "bus budget at {:.0f} kbit/s nominal / {:.0f} kbit/s data: fast loop {:.0f} % ({:.1f} us of frames every {:.0f} us period), "
      "publications {:.2f} %, total {:.0f} %{}",
      config.can.nominal_bitrate_bit_s * 1e-3, config.can.data_bitrate_bit_s * 1e-3, 100.0 * load.fast_loop_fraction,
      load.fast_loop_frame_us, load.period_us, 100.0 * load.publications_fraction, 100.0 * load.total_fraction,
      pmsm::daemon::is_virtual_interface(config.can.interface) ? " (virtual bus: reported, not enforced)" : "");
  // The stored calibration replaces the configured one before the drive starts.
  pmsm::app::StoredCalibration stored = pmsm::app::StoredCalibration::kNotConfigured;
  try {
    pmsm::app::StoredAxis written_by;
    stored = pmsm::app::load_stored_calibration(config.controller, &written_by);
    // Another axis's motor is not this one's: a configuration copied for a second axis, still
    // naming the first one's file, would refer every temperature to the wrong Rs0.
    if (const std::string other = pmsm::app::other_axis_problem(config.controller.calibration_file, written_by,
                                                                pmsm::daemon::stored_axis(config), "controller.calibration.file");
        !other.empty()) {
      throw pmsm::app::CalibrationFileError(other + "; name this axis's own file (its first run calibrates with "
                                                    "startup.calibrate_if_missing), or remove this one if the axis moved");
    }
  } catch (const std::exception& e) {
    spdlog::error("calibration file refused: {}", e.what());
    return o.check ? 1 : kExitConfig;
  }
  // The files the daemon writes, told at start (and under --check) rather than when a
  // calibration completes: a warning, since a drive may run on a read-only calibration it never
  // renews, but what it learns then lives in memory only.
  for (const auto& [key, path] : {std::pair<std::string_view, const std::string&>{"controller.calibration.file",
                                                                                   config.controller.calibration_file},
                                  std::pair<std::string_view, const std::string&>{"controller.thermal.state_file",
                                                                                   config.controller.thermal_state_file}}) {
    if (path.empty()) {
      continue;
    }
    if (const std::string why = unwritable_reason(path); !why.empty()) {
      spdlog::warn("{} = {}: {}: nothing this run learns can be stored there ({} is kept in memory only; "
                   "create the directory, or StateDirectory= in the unit)",
                   key, path, why, key == "controller.calibration.file" ? "a calibration" : "the thermal state");
    }
  }
  if (!config.controller.thermal_state_file.empty()) {
    if (const std::string foreign = pmsm::app::foreign_thermal_state_file(config.controller.thermal_state_file);
        !foreign.empty()) {
      spdlog::warn("controller.thermal.state_file: {}; the thermal state is kept in memory only (name a file of its own)",
                   foreign);
    }
  }
  // A configuration measured to mislead (app::configuration_warnings): defaults that fit only
  // the reference machine on another motor (a newcomer's 1.5 kW servo ran on them and read 11 C
  // RMS off), a method other than fixed-magnitude bipolar on a machine configured as salient,
  // and the like.
  for (const std::string& w : pmsm::app::configuration_warnings(config.controller)) {
    spdlog::warn("{}", w);
  }
  for (const std::string& w : pmsm::daemon::bus_range_warnings(config)) {
    spdlog::warn("{}", w);
  }
  // The shipped unit lets the control thread have SCHED_FIFO 1..90 (LimitRTPRIO=90): above,
  // the start is refused the priority and the drive runs with normal scheduling, the unit
  // active and only the journal's warning saying so. Said by --check; a start says whether the
  // priority was granted (a drop-in may have raised the limit).
  if (o.check && config.rt.priority > kUnitMaxRtPriority) {
    spdlog::warn("rt.priority = {} is above pmsm-thermald@.service's LimitRTPRIO={}: under that unit the control thread "
                 "would get no real-time priority and run with normal scheduling (use 1..{}, or raise LimitRTPRIO in a "
                 "drop-in: systemctl edit pmsm-thermald@INSTANCE)",
                 config.rt.priority, kUnitMaxRtPriority, kUnitMaxRtPriority);
  }
  {
    // A stored calibration without the bridge's voltage: the estimates rest on the configured
    // guess, whose error every estimate shares and the band carries (docs/estimator.md section
    // 4), until an event learns it. Which configurations' events can at all is the scheduler's
    // own rule (InjectionConfig::can_learn_vx), and they do only at light load; fixed-angle and
    // DC pulses turn through the rotor frame and their events seldom qualify (a warm restart
    // without a stored Vx read up to 61 C off, docs/estimator.md section 4).
    const pmsm::core::DriveConfig& d = config.controller.drive;
    const pmsm::core::InjectionConfig& inj = d.injection;
    const bool injects = d.estimator == pmsm::core::EstimatorKind::kInjection && inj.method != pmsm::core::InjectionMethod::kNone;
    if (injects && stored == pmsm::app::StoredCalibration::kLoaded && inj.fit_dead_time && !(d.calibration.vx_std_V > 0.0)) {
      const std::string_view method = pmsm::core::to_string(inj.method);
      const std::string_view separation = pmsm::core::to_string(inj.separation);
      constexpr std::string_view kNoVx =
          "calibration: the stored calibration has no bridge voltage (vx_V: stored by an older version or by hand)";
      if (!inj.can_learn_vx()) {
        spdlog::warn("{}, and {} {} pairs at {} level(s) never learn it (that takes bipolar pairs at two different "
                     "levels or more), so every estimate rests on the configured guess injection.vx_initial_V {:.2f} +- "
                     "{:.2f} V and its band is wide: run a calibration",
                     kNoVx, method, separation, inj.level_count, inj.vx_initial_V, inj.vx_initial_std_V);
      } else if (inj.method != pmsm::core::InjectionMethod::kFixedMagnitude) {
        spdlog::warn("{}; {} {} events learn it only at light load and seldom, so the estimates rest on the configured "
                     "guess injection.vx_initial_V {:.2f} +- {:.2f} V and their band is wide: run a calibration",
                     kNoVx, method, separation, inj.vx_initial_V, inj.vx_initial_std_V);
      } else {
        spdlog::info("{}; the estimates rest on the configured guess injection.vx_initial_V {:.2f} +- {:.2f} V until an "
                     "event at light load (|iq| below injection.vx_learning_max_iq_fraction {:g} of F, electrical speed "
                     "below injection.vx_learning_max_speed_rad_s {:g} rad/s) learns it; a calibration stores one",
                     kNoVx, inj.vx_initial_V, inj.vx_initial_std_V, inj.vx_learning_max_iq_fraction,
                     inj.vx_learning_max_speed_rad_s);
      }
    }
  }
  // A stored Rs0 (a calibration file, or calibration.rs0_ohm given) far off the nameplate and the
  // configured cable: said at every start and by --check (without one, the default is the
  // nameplate's own and nothing is said).
  if (const std::string w =
          pmsm::app::rs0_off_nameplate_warning(config.controller.drive, config.controller.drive.calibration);
      !w.empty()) {
    spdlog::warn("{}", w);
  }
  if (const std::string w =
          pmsm::app::ke0_off_motor_warning(config.controller.drive, config.controller.drive.calibration);
      !w.empty()) {
    spdlog::warn("{}", w);
  }
  if (o.check) {
    // An interface this machine has that is no CAN interface: the start refuses it (exit 2), so
    // --check does too (before, "lo" at 1 kHz passed --check and the unit then failed).
    if (const std::string not_can = pmsm::daemon::non_can_interface_problem(config.can.interface); !not_can.empty()) {
      spdlog::error("{}: {}", o.config_path, not_can);
      return 1;
    }
    // The thermal state as the start would take it: a file it would not use is a warning (the
    // daemon starts without it, from the ambient sensor), not an invalid configuration.
    std::string thermal = "thermal state not configured";
    if (!config.controller.thermal_state_file.empty()) {
      double downtime_s = 0.0;
      std::string why;
      if (const auto s = usable_thermal_state(config, downtime_s, why)) {
        thermal = fmt::format("thermal state usable (winding {:.1f} C, saved {:.0f} s ago)", s->state.winding_C, downtime_s);
        // What the start would say of a bad block, which costs only itself.
        warn_unused_thermal_blocks(*s, true);
      } else if (why.empty()) {
        thermal = "thermal state missing";
      } else {
        spdlog::warn("thermal state not usable: {}; the daemon would start from the ambient sensor", why);
        thermal = "thermal state not usable";
      }
    }
    std::printf("%s: OK (node %d on %s, %s; calibration %s; %s)\n", o.config_path.c_str(), config.can.node,
                config.can.interface.c_str(), budget.c_str(), std::string(pmsm::app::to_string(stored)).c_str(),
                thermal.c_str());
    return pmsm::cli::exit_with_standard_output_checked("pmsm-thermald", 0, kExitIo);
  }
  spdlog::info("pmsm-thermald {} starting: config {}, node {} on {}", PMSM_VERSION, o.config_path, config.can.node,
               config.can.interface);
  spdlog::info("{}", budget);
  spdlog::info("calibration: {}{}", pmsm::app::to_string(stored),
               stored == pmsm::app::StoredCalibration::kLoaded
                   ? fmt::format(" (Rs0 {:.5f} ohm at {:.1f} C)", config.controller.drive.calibration.rs0_ohm,
                                 config.controller.drive.calibration.t0_C)
                   : std::string{});

  // CAN: the RT socket receives exactly this node's samples and commands; the publishing
  // socket nothing until the publisher installs its filters (this node's published
  // identifiers: another sender of them is a second daemon on this node).
  const protocol::FilterSet filters = protocol::receive_filters(protocol::Role::kDaemon, static_cast<protocol::NodeId>(config.can.node));
  pmsm::hal::SocketCanConfig rt_bus_config;
  rt_bus_config.interface = config.can.interface;
  rt_bus_config.fd = true;
  rt_bus_config.filters = std::vector<pmsm::hal::CanFilter>(filters.view().begin(), filters.view().end());
  // The controller's state changes reach the loop (bus-off, its restart, error-passive): a
  // drive whose controller went bus-off hears no sample and would only say SENSOR_TIMEOUT.
  rt_bus_config.error_mask = pmsm::daemon::DriveLoop::kErrorClasses;
  rt_bus_config.io_uring = config.can.io_uring;
  pmsm::hal::Status error;
  std::unique_ptr<pmsm::hal::SocketCanBus> rt_bus = pmsm::hal::SocketCanBus::open(rt_bus_config, error);
  if (!rt_bus) {
    return bus_open_failure("cannot open the CAN bus", config.can.interface, error);
  }
  pmsm::hal::SocketCanConfig pub_bus_config;
  pub_bus_config.interface = config.can.interface;
  pub_bus_config.fd = true;
  pub_bus_config.filters = std::vector<pmsm::hal::CanFilter>{};
  std::unique_ptr<pmsm::hal::SocketCanBus> pub_bus = pmsm::hal::SocketCanBus::open(pub_bus_config, error);
  if (!pub_bus) {
    return bus_open_failure("cannot open the CAN bus for publishing", config.can.interface, error);
  }
  if (rt_bus->exchanges_in_one_call()) {
    spdlog::info("CAN: each period's answer and wait for the next sample in one system call (io_uring)");
  } else if (config.can.io_uring) {
    spdlog::info("CAN: each period's answer and wait for the next sample in separate system calls (no io_uring "
                 "here: the kernel lacks it or refuses it)");
  } else {
    spdlog::info("CAN: each period's answer and wait for the next sample in separate system calls (can.io_uring = false)");
  }

  // GPIO: the gate enable is requested inactive; a configured chip or line that is missing
  // is an error, no chip configured is the null backend.
  std::unique_ptr<pmsm::hal::GateEnableOutput> gate;
  std::unique_ptr<pmsm::hal::FaultInput> fault_input;
  try {
    pmsm::hal::GpioLineConfig enable{config.gpio.chip, static_cast<unsigned>(std::max(config.gpio.enable_line, 0)),
                                     config.gpio.enable_active_low};
    gate = pmsm::hal::make_gate_enable_output(enable);
    pmsm::hal::GpioLineConfig fault{config.gpio.fault_line >= 0 ? config.gpio.chip : std::string{},
                                    static_cast<unsigned>(std::max(config.gpio.fault_line, 0)), config.gpio.fault_active_low};
    fault_input = pmsm::hal::make_fault_input(fault);
  } catch (const std::exception& e) {
    // A chip or line the configuration names and the machine does not have (or has busy) is not
    // cured by restarting every second: exit 2, which the unit does not restart.
    spdlog::error("GPIO: {} (a configuration to fix: not retried)", e.what());
    return kExitConfig;
  }
  spdlog::info("GPIO: gate enable {}, fault input {}", gate->describe(), fault_input->describe());

  if (config.rt.lock_memory) {
    if (const pmsm::hal::Status s = pmsm::hal::prepare_memory_for_realtime(); !s.ok()) {
      spdlog::warn("{}", s.message());
    } else {
      spdlog::info("memory locked (mlockall), heap trimming and mmap'd allocations off");
    }
  }
  if (const pmsm::hal::Status s = pmsm::hal::install_stop_signals(); !s.ok()) {
    spdlog::warn("{}", s.message());
  }
  std::atomic<bool>& stop = pmsm::hal::stop_requested();

  pmsm::daemon::PublicationRing ring;
  pmsm::daemon::DriveLoop loop(config, *rt_bus, ring);
  restore_thermal_state(config, loop);
  pmsm::daemon::Publisher publisher(config, *pub_bus, loop);
  pmsm::hal::RecordDrain<pmsm::daemon::PublicationRecord, pmsm::daemon::PublicationRing::capacity()> drain(
      ring, [&](const pmsm::daemon::PublicationRecord& r) { publisher.handle(r); }, 5ms, [&] { publisher.after_batch(); });

  // The RT thread: the drain thread above was created first, so it keeps normal scheduling.
  std::promise<RtSetup> setup_promise;
  std::future<RtSetup> setup_future = setup_promise.get_future();
  std::thread rt_thread([&] {
    RtSetup setup;
    if (config.rt.priority > 0) {
      if (const pmsm::hal::Status s = pmsm::hal::set_realtime_priority(config.rt.priority); !s.ok()) {
        setup.priority_warning = s.message();
      } else {
        setup.priority_granted = true;
      }
    }
    if (config.rt.cpu >= 0) {
      const int cpus[] = {config.rt.cpu};
      if (const pmsm::hal::Status s = pmsm::hal::set_cpu_affinity(cpus); !s.ok()) {
        setup.affinity_warning = s.message();
      }
    }
    pmsm::hal::prefault_stack();
    setup_promise.set_value(setup);
    loop.run(stop);
  });
  const RtSetup setup = setup_future.get();
  if (setup.priority_granted) {
    spdlog::info("control thread: SCHED_FIFO priority {} granted", config.rt.priority);
  } else if (config.rt.priority > 0) {
    spdlog::warn("control thread runs without real-time priority: {}", setup.priority_warning);
  }
  if (!setup.affinity_warning.empty()) {
    spdlog::warn("control thread not pinned: {}", setup.affinity_warning);
  }

  // The fault input: woken by its edge events (or polled), straight into the loop's flag.
  pmsm::daemon::FaultWatchStats fault_watch_stats;
  std::thread fault_thread([&] {
    bool read_failing = false;
    pmsm::daemon::watch_fault_input(
        *fault_input, stop, pmsm::hal::stop_signal_fd(),
        [&](bool fault, bool read_ok) {
          loop.set_gpio_fault(fault);
          if (!read_ok && !read_failing) {
            spdlog::error("GPIO: cannot read the fault input {} ({}): treated as a fault", fault_input->describe(),
                          pmsm::hal::errno_text(fault_input->last_error_number()));
          } else if (read_ok && read_failing) {
            spdlog::info("GPIO: the fault input reads again");
          }
          read_failing = !read_ok;
        },
        fault_watch_stats);
  });

  sd_notify(0, "READY=1\nSTATUS=controlling");
  spdlog::info("ready: waiting for SENSOR_SAMPLE frames of node {} on {}", config.can.node, config.can.interface);

  // Watchdog: WATCHDOG=1 only while the RT loop's heartbeat advances (a stalled control loop
  // lets systemd kill and restart the daemon).
  std::uint64_t watchdog_usec = 0;
  const bool watchdog = sd_watchdog_enabled(0, &watchdog_usec) > 0 && watchdog_usec > 0;
  const auto watchdog_every = std::chrono::microseconds{watchdog_usec / 2};
  auto next_watchdog = std::chrono::steady_clock::now();
  std::uint64_t last_heartbeat = loop.heartbeat();
  bool gate_state = false;
  bool gate_write_failed = false;
  while (!stop.load(std::memory_order_relaxed)) {
    std::this_thread::sleep_for(1ms);
    // The gate-enable line follows what the loop commands the power stage. A write that fails
    // is tried again every millisecond (logged once until it succeeds): the line's state is
    // what was written, not what was wanted.
    const bool gates = loop.gates_enabled();
    if (gates != gate_state) {
      if (gate->set_active(gates)) {
        gate_state = gates;
        if (gate_write_failed) {
          spdlog::info("GPIO: the gate enable is set {} again", gates ? "on" : "off");
        }
        gate_write_failed = false;
      } else if (!gate_write_failed) {
        gate_write_failed = true;
        spdlog::error("GPIO: cannot set the gate enable {} (tried again every millisecond)", gates ? "on" : "off");
      }
    }
    if (watchdog && std::chrono::steady_clock::now() >= next_watchdog) {
      next_watchdog += watchdog_every;
      const std::uint64_t beat = loop.heartbeat();
      if (beat != last_heartbeat) {
        last_heartbeat = beat;
        sd_notify(0, "WATCHDOG=1");
      }
    }
  }
  sd_notify(0, "STOPPING=1");
  // The gates first: the threads take up to a sample timeout (the loop's last "off" to the
  // power stage) or a reopen slice to end.
  if (!gate->set_active(false)) {
    spdlog::error("GPIO: cannot set the gate enable off at the stop");
  }
  fault_thread.join();
  rt_thread.join();
  drain.stop();
  // (The loop gave the ring a second at its stop to take its backlog: what it could not is
  // counted, and said here, after the last of the publishing thread's reports.)
  if (const std::uint64_t lost = loop.stats().events_lost; lost != 0U) {
    spdlog::error("{} event record(s) lost while this daemon ran (fault changes, a calibration's start, end or "
                  "store): the publishing thread did not keep up with the control loop",
                  lost);
  }
  if (loop.node().controller().telemetry().thermal_valid) {
    publisher.store_thermal_state(loop.node().controller().thermal_state(), loop.node().ambient_C());
  }
  spdlog::info("stopped: {}", publisher.summary());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"pmsm-thermald: PMSM drive controller with winding-temperature estimation, on CAN (one axis per process)"};
  Options o;
  app.add_option("--config", o.config_path,
                 "configuration file (TOML), e.g. /etc/pmsm-thermal/axis1.toml; required except with --keys and --version")
      ->check(pmsm::cli::file_name());
  CLI::Option* check =
      app.add_flag("--check", o.check, "validate the configuration (and the stored calibration; the thermal state is reported) and exit: 0 valid, 1 not");
  // (--keys prints and exits: with --check it would answer 0 having validated nothing.)
  app.add_flag("--keys", o.keys, "print every configuration key of the daemon's own sections as Markdown and exit")
      ->excludes(check);
  app.add_option("--log-level", o.log_level, "trace, debug, info, warning (or warn), error: as the log lines name them")
      ->check(CLI::IsMember({"trace", "debug", "info", "warning", "warn", "error"}))
      ->capture_default_str();
  app.set_version_flag("--version", std::string("pmsm-thermald ") + PMSM_VERSION);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; a bad command line is a configuration error like a bad
    // file (exit 2, which the unit does not restart on), not one of CLI11's own codes.
    return pmsm::cli::exit_on_parse_error(app, e, kExitConfig, "pmsm-thermald", kExitIo);
  }
  if (o.keys) {
    (void)pmsm::cli::write_standard_output(pmsm::daemon::daemon_keys_markdown());
    return pmsm::cli::exit_with_standard_output_checked("pmsm-thermald", 0, kExitIo);
  }
  if (o.config_path.empty()) {
    std::fprintf(stderr, "pmsm-thermald: --config FILE is required (see --help)\n");
    return kExitConfig;
  }
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pmsm-thermald: %s\n", e.what());
    return kExitIo;
  }
}
