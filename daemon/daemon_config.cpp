#include "daemon_config.hpp"

#include <net/if.h>
#include <net/if_arp.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <initializer_list>
#include <sstream>

#include <fmt/format.h>
#include <toml++/toml.h>

#include "config_schema.hpp"
#include "key_rules.hpp"
#include "supervisor_config.hpp"
#include "pmsm/hal/protocol.hpp"
#include "pmsm/hal/socketcan.hpp"

namespace pmsm::daemon {
namespace {

// What this machine says of a configured interface's name, for the bus-load refusal: nothing
// for a CAN interface (or one whose type cannot be read), else that it has none by that name or
// that the one it has is not CAN.
std::string interface_on_this_machine(const std::string& name) {
  if (::if_nametoindex(name.c_str()) == 0) {
    return fmt::format("; this machine has no interface '{}' either (a name mistyped?)", name);
  }
  const int type = non_can_link_type(name);
  return type < 0 ? std::string{}
                  : fmt::format("; and '{}' on this machine is not a CAN interface at all (its link type is {}, CAN's {})",
                                name, type, ARPHRD_CAN);
}

using app::ConfigError;
using app::ConfigSchema;
using D = DaemonConfig;

const ConfigSchema<D>& schema() {
  static const ConfigSchema<D> s = [] {
    ConfigSchema<D> c;
    // [can]
    c.string("can.interface", [](D& d) -> std::string& { return d.can.interface; },
             "CAN interface of the fast loop and the publications (vcan0 in tests, can0 on a controller); CAN FD (MTU 72).");
    c.integer("can.node", [](D& d) -> int& { return d.can.node; }, app::between(0, 15),
              "Node id of this axis, added to every CAN ID (several axes share one bus).");
    c.real("can.nominal_bitrate_bit_s", [](D& d) -> double& { return d.can.nominal_bitrate_bit_s; }, app::between(1e4, 1e6),
           "bit/s", "The real bus's nominal (arbitration) bit rate, for the load budget.");
    c.real("can.data_bitrate_bit_s", [](D& d) -> double& { return d.can.data_bitrate_bit_s; }, app::between(1e4, 1.5e7),
           "bit/s", "The real bus's CAN FD data-phase bit rate, for the load budget.");
    c.real("can.max_bus_load", [](D& d) -> double& { return d.can.max_bus_load; }, app::between(0.05, 1.0), "",
           "Refuse to start when the fast loop and the publications would load the real bus above this fraction.");
    c.real("can.sample_timeout_ms", [](D& d) -> double& { return d.can.sample_timeout_ms; }, app::between(0.05, 1000), "ms",
           "Wall time without a SENSOR_SAMPLE that counts as one missing period (supervisor.sensor_timeout_periods of "
           "them trip the sensor-timeout fault). Above the period: lockstep plants run slower than real time.");
    c.real("can.reopen_interval_ms", [](D& d) -> double& { return d.can.reopen_interval_ms; }, app::between(1, 60000), "ms",
           "How often a lost interface is checked for and the socket reopened.");
    c.boolean("can.io_uring", [](D& d) -> bool& { return d.can.io_uring; },
              "Send each period's answer and wait for the next sample in one system call (io_uring), where the kernel "
              "has it and allows it (the log says which); false: a send, a poll and a read.");
    // [rt]
    c.integer("rt.priority", [](D& d) -> int& { return d.rt.priority; }, app::between(0, 99),
              "SCHED_FIFO priority of the control thread (0: normal scheduling). Refused without LimitRTPRIO= or "
              "CAP_SYS_NICE: a warning, not a failure.");
    c.integer("rt.cpu", [](D& d) -> int& { return d.rt.cpu; }, app::between(-1, 1023), "Pin the control thread to this CPU (-1: no pinning).");
    c.boolean("rt.lock_memory", [](D& d) -> bool& { return d.rt.lock_memory; },
              "mlockall plus no heap trimming and no mmap'd allocations (cactus-rt's set-up).");
    // [gpio]
    c.string("gpio.chip", [](D& d) -> std::string& { return d.gpio.chip; },
             "GPIO chip (e.g. gpiochip0 or /dev/gpiochip0); empty: no GPIO (null backend).");
    c.integer("gpio.enable_line", [](D& d) -> int& { return d.gpio.enable_line; }, app::between(-1, 4095),
              "Gate-enable output line offset (requested inactive; asserted only while the drive runs).");
    c.integer("gpio.fault_line", [](D& d) -> int& { return d.gpio.fault_line; }, app::between(-1, 4095),
              "Power-stage fault input line offset (-1: none); active trips the gpio-fault fault.");
    c.boolean("gpio.enable_active_low", [](D& d) -> bool& { return d.gpio.enable_active_low; }, "The gate enable is active low.");
    c.boolean("gpio.fault_active_low", [](D& d) -> bool& { return d.gpio.fault_active_low; }, "The fault input is active low.");
    // [publish]
    c.real("publish.thermal_estimate_s", [](D& d) -> double& { return d.publish.thermal_estimate_s; }, app::between(0, 3600), "s",
           "THERMAL_ESTIMATE period, at least the control period (0: never).");
    c.real("publish.resistance_estimate_s", [](D& d) -> double& { return d.publish.resistance_estimate_s; }, app::between(0, 3600), "s",
           "RESISTANCE_ESTIMATE period, at least the control period, besides one per new estimate (0: only new estimates).");
    c.real("publish.drive_status_s", [](D& d) -> double& { return d.publish.drive_status_s; }, app::between(0, 3600), "s",
           "DRIVE_STATUS period, at least the control period (0: never).");
    c.real("publish.heartbeat_s", [](D& d) -> double& { return d.publish.heartbeat_s; }, app::between(0, 3600), "s",
           "HEARTBEAT period, at least the control period (0: never).");
    c.real("publish.fault_repeat_s", [](D& d) -> double& { return d.publish.fault_repeat_s; }, app::between(0, 3600), "s",
           "Latched faults are repeated this often (at least the control period), besides one FAULT frame per change (0: changes only).");
    c.real("publish.stale_after_s", [](D& d) -> double& { return d.publish.stale_after_s; }, app::between(0.1, 1e6), "s",
           "THERMAL_ESTIMATE says stale when no resistance estimate was accepted for this long.");
    // [supervisor]: the keys a scenario's [supervisor] shares (supervisor_config.hpp).
    app::add_supervisor_keys<D>(c, [](D& d) -> core::SupervisorConfig& { return d.supervisor; });
    // [startup]
    c.boolean("startup.calibrate_if_missing", [](D& d) -> bool& { return d.startup.calibrate_if_missing; },
              "With controller.calibration.file set but absent, calibrate at the ambient sensor's temperature the first time the "
              "drive runs (not while the sensor is held at its last reading: then the first time it runs with the sensor "
              "reporting).");
    return c;
  }();
  return s;
}

// Bits on the wire of one standard-ID frame: classic CAN at the nominal rate, or CAN FD with
// the data phase (from the BRS bit to the CRC delimiter) at the data rate. Worst-case bit
// stuffing on the stuffed fields; CAN FD's fixed stuff bits in the CRC field.
double frame_time_s(std::size_t bytes, bool fd, double nominal, double data) {
  const auto payload = static_cast<double>(8 * bytes);
  if (!fd) {
    // SOF, ID 11, RTR, IDE, r0, DLC 4, data, CRC 15 (stuffed: 34 + 8n bits), then CRC
    // delimiter, ACK 2, EOF 7, IFS 3.
    const double stuffed = 34.0 + payload;
    return (stuffed + std::floor((stuffed - 1.0) / 4.0) + 13.0) / nominal;
  }
  // Arbitration phase at the nominal rate: SOF, ID 11, RRS, IDE, FDF, res, BRS (17 bits,
  // stuffed) plus CRC delimiter, ACK 2, EOF 7, IFS 3 after the data phase.
  const double arbitration = 17.0 + std::floor(16.0 / 4.0) + 13.0;
  // Data phase: ESI, DLC 4, data (stuffed), stuff count 4, CRC 17 (up to 16 bytes) or 21,
  // and one fixed stuff bit per 4 bits of the stuff count and CRC.
  const double crc = bytes <= 16 ? 17.0 : 21.0;
  const double stuffed = 5.0 + payload;
  const double data_bits = stuffed + std::floor(stuffed / 4.0) + 4.0 + crc + std::ceil((4.0 + crc) / 4.0);
  return arbitration / nominal + data_bits / data;
}

// Every broken rule between keys, one line each ("" when none). The rules that involve the
// drive's keys, or the supervisor's defaults derived from them, run only when the drive's
// sections parsed (`controller_valid`): against a default drive they would report
// contradictions the file does not have. `root` tells a given key from a default.
std::string check_cross_keys(const DaemonConfig& c, const toml::table& root, const std::string& source,
                             bool controller_valid) {
  common::KeyRules rules(root, source);
  if (const std::string problem = hal::can_interface_name_problem(c.can.interface); !problem.empty()) {
    rules.at("can.interface", "can.interface: " + problem);
  }
  rules.append(app::check_supervisor_own_rules(c.supervisor, root, source));
  if (c.gpio.chip.empty() != (c.gpio.enable_line < 0)) {
    rules.at(c.gpio.chip.empty() ? "gpio.enable_line" : "gpio.chip",
             fmt::format("gpio.chip and gpio.enable_line go together (chip '{}', enable_line {})", c.gpio.chip,
                         c.gpio.enable_line));
  }
  if (c.gpio.fault_line >= 0 && c.gpio.chip.empty()) {
    rules.at("gpio.fault_line", "gpio.fault_line needs gpio.chip");
  }
  if (c.gpio.fault_line >= 0 && c.gpio.fault_line == c.gpio.enable_line) {
    rules.at("gpio.fault_line", fmt::format("gpio.fault_line and gpio.enable_line are both line {}: one line cannot "
                                            "be the gate enable output and the fault input",
                                            c.gpio.fault_line));
  }
  if (!controller_valid) {
    return rules.errors();
  }
  rules.append(app::check_supervisor_rules(c.supervisor, c.controller, root, source));
  const core::SupervisorConfig& s = c.supervisor;
  // A publication comes at most once a control period: a shorter period is a typo (1e-9 s
  // passed --check, with a bus load of 13,500,000 % computed from it).
  for (const auto& publication : {std::pair<std::string_view, double>{"publish.thermal_estimate_s", c.publish.thermal_estimate_s},
                                   {"publish.resistance_estimate_s", c.publish.resistance_estimate_s},
                                   {"publish.drive_status_s", c.publish.drive_status_s},
                                   {"publish.heartbeat_s", c.publish.heartbeat_s},
                                   {"publish.fault_repeat_s", c.publish.fault_repeat_s}}) {
    // (Named copies: clang 14 cannot capture a structured binding in the lambda below.)
    const std::string_view key = publication.first;
    const double every_s = publication.second;
    if (every_s > 0.0 && every_s < c.controller.drive.period_s) {
      rules.with({key, "controller.control.period_s"}, [&](const auto& value) {
        return value(key, every_s, "s") + " is shorter than the control period " +
               value("controller.control.period_s", c.controller.drive.period_s, "s") +
               ": the drive publishes once a period at most (0 turns the periodic frames off)";
      });
    }
  }
  // A command timeout within one control period would fault in every period a command did not
  // come in (1e-5 s passed --check).
  if (s.command_timeout_s > 0.0 && !(s.command_timeout_s > c.controller.drive.period_s)) {
    rules.with({"supervisor.command_timeout_s", "controller.control.period_s"}, [&](const auto& value) {
      return value("supervisor.command_timeout_s", s.command_timeout_s, "s") + " must be above the control period " +
             value("controller.control.period_s", c.controller.drive.period_s, "s") +
             ", or 0 (off): a drive enabled would fault in every period without a fresh DRIVE_COMMAND";
    });
  }
  if (const double period_ms = 1e3 * c.controller.drive.period_s; !(c.can.sample_timeout_ms > period_ms)) {
    rules.with({"can.sample_timeout_ms", "controller.control.period_s"}, [&](const auto& value) {
      return value("can.sample_timeout_ms", c.can.sample_timeout_ms, "ms") + " must be above the control period " +
             value("controller.control.period_s", c.controller.drive.period_s, "s") + ": every period would count as missing";
    });
  }
  return rules.errors();
}

// A configured value beyond a signal's range, as a warning naming both.
std::optional<std::string> beyond_signal(std::string_view key, double value, std::string_view unit,
                                         const hal::protocol::SignalDef& signal, std::string_view what) {
  if (!(value > signal.maximum)) {
    return std::nullopt;
  }
  return fmt::format("{} ({} {}) lies beyond DRIVE_STATUS {}'s range (up to {} {}): {}, the frame reads {} {}, not the "
                     "drive's value (docs/protocol.md)",
                     key, common::format_number(value), unit, signal.name, common::format_number(signal.maximum), unit, what,
                     common::format_number(signal.maximum), unit);
}

// The supervisor's defaults for a drive: relative to its motor, ADCs and bus
// (app::default_supervisor_config), and a command timeout: a daemon that is enabled expects a
// supervisor that keeps talking.
core::SupervisorConfig daemon_supervisor_defaults(const app::ControllerConfig& controller) {
  core::SupervisorConfig s = app::default_supervisor_config(controller);
  s.command_timeout_s = 0.5;
  return s;
}

}  // namespace

DaemonConfig parse_daemon_config(const std::string& text, const std::filesystem::path& source) {
  const toml::table root = common::parse_toml(text, source.string());
  DaemonConfig c;
  c.source = source;
  // The drive first: the supervisor's defaults are relative to it.
  static const toml::table kEmpty;
  // Every bad key of the file at once: the drive's sections' errors, then the daemon's.
  std::string errors;
  try {
    const toml::table* controller_table = common::optional_section(root, "controller", source.string());
    c.controller = app::parse_controller_config(controller_table != nullptr ? *controller_table : kEmpty, source.string(),
                                                {}, "controller.");
  } catch (const ConfigError& e) {
    errors = e.what();
  }
  const bool controller_valid = errors.empty();
  c.supervisor = daemon_supervisor_defaults(c.controller);
  std::vector<std::string> foreign{"controller"};
  bool daemon_valid = true;
  try {
    schema().apply(root, c, source.string(), foreign);
  } catch (const ConfigError& e) {
    errors += (errors.empty() ? "" : "\n") + std::string(e.what());
    daemon_valid = false;
  }
  // Every broken rule too, as far as the keys they relate parsed.
  if (daemon_valid) {
    const std::string broken = check_cross_keys(c, root, source.string(), controller_valid);
    errors += (errors.empty() || broken.empty() ? "" : "\n") + broken;
  }
  if (!errors.empty()) {
    throw ConfigError(errors);
  }
  const BusLoad load = bus_load(c);
  // A vcan interface has no bit timing: the budget is logged at start-up, not enforced.
  if (!is_virtual_interface(c.can.interface) && load.total_fraction > c.can.max_bus_load) {
    // Located at the first of the keys it follows from that the file gives (the interface that
    // makes it a real bus, as a rule of several keys is).
    const std::string at = common::KeyRules::location_of_first(
        root, {"can.interface", "can.data_bitrate_bit_s", "can.nominal_bitrate_bit_s", "controller.control.period_s",
               "can.max_bus_load"},
        source.string());
    throw ConfigError(at + fmt::format(
        "the fast loop ({:.0f} % of the bus: one SENSOR_SAMPLE and one INVERTER_COMMAND, {:.1f} us, every {:.1f} us "
        "period) and the publications ({:.1f} %) need {:.0f} % of a bus at can.nominal_bitrate_bit_s {:.0f} / "
        "can.data_bitrate_bit_s {:.0f}, above can.max_bus_load {:.0f} %: raise can.data_bitrate_bit_s or "
        "controller.control.period_s, or lower the publish.* rates (can.interface '{}' is taken for a physical CAN bus "
        "with these bit rates; only a name beginning with 'vcan' is a virtual bus, whose load is not enforced)",
        100.0 * load.fast_loop_fraction, load.fast_loop_frame_us, load.period_us,
        100.0 * load.publications_fraction, 100.0 * load.total_fraction, c.can.nominal_bitrate_bit_s,
        c.can.data_bitrate_bit_s, 100.0 * c.can.max_bus_load, c.can.interface) +
        // A name mistyped reads as a physical bus too: say that this machine has no such
        // interface, or that the one it has is no CAN interface (e.g. "lo").
        interface_on_this_machine(c.can.interface));
  }
  return c;
}

DaemonConfig load_daemon_config(const std::filesystem::path& path) {
  return parse_daemon_config(common::read_config_file(path, "daemon configuration"), path);
}

bool is_virtual_interface(const std::string& interface) { return interface.rfind("vcan", 0) == 0; }

int non_can_link_type(const std::string& name) {
  if (name.empty() || name.find('/') != std::string::npos || ::if_nametoindex(name.c_str()) == 0) {
    return -1;
  }
  std::ifstream type_file("/sys/class/net/" + name + "/type");
  int type = -1;
  return type_file >> type && type != ARPHRD_CAN ? type : -1;
}

std::string non_can_interface_problem(const std::string& name) {
  const int type = non_can_link_type(name);
  return type < 0 ? std::string{}
                  : fmt::format("can.interface '{}' on this machine is not a CAN interface (its link type is {}, CAN's "
                                "{}): the start would refuse it",
                                name, type, ARPHRD_CAN);
}

app::StoredAxis stored_axis(const DaemonConfig& config) {
  return {config.can.interface, static_cast<int>(config.can.node)};
}

// The key table shows what a file without the key gets: the supervisor's defaults follow the
// default drive (Table I), as they follow the configured one in parse_daemon_config().
std::string daemon_keys_markdown() {
  DaemonConfig c;
  c.supervisor = daemon_supervisor_defaults(c.controller);
  return schema().markdown(c);
}

std::vector<std::string> bus_range_warnings(const DaemonConfig& config) {
  namespace ds = hal::protocol::drive_status;
  const core::DriveConfig& d = config.controller.drive;
  std::vector<std::string> out;
  for (const std::optional<std::string>& w :
       {beyond_signal("controller.derating.max_current_A", d.derating.max_current_A, "A", ds::kCurrentLimit,
                      "while the limit is above it"),
        beyond_signal("controller.control.max_torque_Nm", d.speed.max_torque_Nm, "Nm", ds::kTorque,
                      "at a torque above it"),
        beyond_signal("supervisor.overspeed_rad_s", config.supervisor.overspeed_rad_s, "rad/s", ds::kSpeed,
                      "at a speed above it (short of the trip)")}) {
    if (w) {
      out.push_back(*w);
    }
  }
  return out;
}

BusLoad bus_load(const DaemonConfig& c) {
  namespace protocol = hal::protocol;
  const double nominal = c.can.nominal_bitrate_bit_s;
  const double data = c.can.data_bitrate_bit_s;
  auto frame_s = [&](protocol::MessageType type) {
    const protocol::MessageDef& m = protocol::kMessages[static_cast<std::size_t>(type)];
    return frame_time_s(m.length, m.fd, nominal, data);
  };
  BusLoad b;
  const double period = c.controller.drive.period_s;
  b.period_us = 1e6 * period;
  const double fast = frame_s(protocol::MessageType::kSensorSample) + frame_s(protocol::MessageType::kInverterCommand);
  b.fast_loop_frame_us = 1e6 * fast;
  b.fast_loop_fraction = fast / period;
  auto rate = [](double every_s) { return every_s > 0.0 ? 1.0 / every_s : 0.0; };
  // Events (injection reports, new estimates) at most a few per second: counted at 10 Hz.
  b.publications_fraction = frame_s(protocol::MessageType::kThermalEstimate) * rate(c.publish.thermal_estimate_s) +
                            frame_s(protocol::MessageType::kResistanceEstimate) * (rate(c.publish.resistance_estimate_s) + 1.0) +
                            frame_s(protocol::MessageType::kDriveStatus) * rate(c.publish.drive_status_s) +
                            (frame_s(protocol::MessageType::kHeartbeat) + frame_s(protocol::MessageType::kLoopTiming)) *
                                rate(c.publish.heartbeat_s) +
                            frame_s(protocol::MessageType::kReceiveStatus) * (rate(c.publish.heartbeat_s) + 10.0) +
                            frame_s(protocol::MessageType::kInjectionReport) * 10.0 +
                            frame_s(protocol::MessageType::kFault) * 2.0 * rate(c.publish.fault_repeat_s);
  b.total_fraction = b.fast_loop_fraction + b.publications_fraction;
  return b;
}

}  // namespace pmsm::daemon
