// pmsm-thermald's configuration file: [can], [rt], [gpio], [publish], [supervisor],
// [startup] and the drive's own sections under [controller] (the same schema as a
// simulation scenario's [controller] block: one pastes into the other). Every key is in
// docs/daemon.md with its default, range and meaning (generated: `pmsm-thermald --keys`).
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include "calibration_file.hpp"
#include "controller_config.hpp"
#include "drive_node.hpp"
#include "pmsm/core/supervisor.hpp"

namespace pmsm::daemon {

struct CanSection {
  std::string interface = "vcan0";
  int node = 0;                          // node id 0..15, added to every CAN ID
  // The real bus this deployment runs on, for the load budget checked at start-up.
  double nominal_bitrate_bit_s = 1.0e6;  // arbitration phase (classic CAN: the whole frame)
  double data_bitrate_bit_s = 8.0e6;     // CAN FD data phase
  double max_bus_load = 0.7;             // refuse to start above this fraction of the bus
  double sample_timeout_ms = 2.0;        // wall time without a sample counted as one missing period
  double reopen_interval_ms = 200.0;     // how often a lost interface is checked for
  bool io_uring = true;                  // a period's answer and wait in one system call where the kernel allows
};

struct RtSection {
  int priority = 80;      // SCHED_FIFO priority of the control thread (0: leave it normal)
  int cpu = -1;           // pin the control thread to this CPU (-1: no pinning)
  bool lock_memory = true;
};

struct GpioSection {
  std::string chip;       // empty: no GPIO (null backend)
  int enable_line = -1;   // gate-enable output line offset
  int fault_line = -1;    // fault input line offset (-1: none)
  bool enable_active_low = false;
  bool fault_active_low = true;
};

struct StartupSection {
  // With controller.calibration.file configured but absent (a new motor): calibrate at the
  // ambient sensor's temperature the first time the drive runs.
  bool calibrate_if_missing = true;
};

struct DaemonConfig {
  CanSection can;
  RtSection rt;
  GpioSection gpio;
  app::PublishRates publish;
  core::SupervisorConfig supervisor;
  StartupSection startup;
  app::ControllerConfig controller;
  std::filesystem::path source;
};

// Loads and checks a daemon configuration file. Throws app::ConfigError naming file:line and
// key, or the file when it cannot be read.
[[nodiscard]] DaemonConfig load_daemon_config(const std::filesystem::path& path);
[[nodiscard]] DaemonConfig parse_daemon_config(const std::string& text, const std::filesystem::path& source);

// Markdown tables of the daemon's own keys (docs/daemon.md).
[[nodiscard]] std::string daemon_keys_markdown();

// Limits a configuration lets the drive reach beyond what a published signal can carry: the
// frame then reads the signal's end (DRIVE_STATUS CurrentLimit, Torque, Speed), a plausible
// number that is not the drive's. One warning each, naming the key and the signal; empty when
// everything fits.
[[nodiscard]] std::vector<std::string> bus_range_warnings(const DaemonConfig& config);

// The load the fast loop and the publications put on the configured real bus.
struct BusLoad {
  double fast_loop_fraction = 0.0;    // SENSOR_SAMPLE + INVERTER_COMMAND every period
  double publications_fraction = 0.0; // the user-facing frames at their rates
  double total_fraction = 0.0;
  double fast_loop_frame_us = 0.0;    // one sample + one command on the wire
  double period_us = 0.0;
  bool fd_needed = true;              // the fast frames are CAN FD
};
[[nodiscard]] BusLoad bus_load(const DaemonConfig& config);
// vcan*: no bit timing, so the load budget is reported, not enforced.
[[nodiscard]] bool is_virtual_interface(const std::string& interface);
// The ARPHRD_* link type of an interface this machine has (/sys/class/net/NAME/type) when it is
// not CAN's; -1 for a CAN interface, none by that name, or a type that cannot be read.
[[nodiscard]] int non_can_link_type(const std::string& name);
// Why can.interface, present on this machine, is not a CAN interface (e.g. "lo"), or "": for
// --check, which says what the start would (it refuses such an interface, exit 2).
[[nodiscard]] std::string non_can_interface_problem(const std::string& name);
// The axis this daemon is, as its stored calibration and thermal state record it.
[[nodiscard]] app::StoredAxis stored_axis(const DaemonConfig& config);

}  // namespace pmsm::daemon
