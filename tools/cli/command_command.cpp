// pmsm-thermal command: the supervisor's side of the protocol from a shell. Sends E2E-
// protected DRIVE_COMMAND frames (CRC-8 + alive counter) at a steady rate so that the
// daemon's command timeout stays satisfied, plus optional one-off INJECTION_COMMAND and
// CALIBRATION_COMMAND frames, for a given time or until SIGINT/SIGTERM; a last DRIVE_COMMAND
// with enable off at the end.
//
// Every run starts its alive counters at 0, where the daemon's receiver still holds the last
// run's: its first frame of each stream is then refused (a repeated counter or a jump) and
// re-synchronises the stream (docs/protocol.md, "The alive-counter state machine"). The cyclic
// DRIVE_COMMAND loses one frame to that; a one-off request would be lost, so each is preceded
// by a frame of the same stream that asks for nothing.
//
//   pmsm-thermal command --iface vcan0 --node 1 --mode speed --speed 100 --duration 30
#include <cctype>
#include <chrono>
#include <cstdio>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "cli_validators.hpp"
#include "commands.hpp"
#include "daemon_answers.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/signals.hpp"
#include "pmsm/hal/socketcan.hpp"

namespace pmsm::app {
namespace {

namespace protocol = hal::protocol;

struct CommandOptions {
  std::string iface = "vcan0";
  int node = 0;
  std::string mode = "speed";
  std::optional<double> speed_rad_s;
  std::optional<double> torque_Nm;
  double period_ms = 50.0;
  std::optional<double> duration_s;
  std::optional<double> calibrate_at_C;
  bool inject_now = false;
  std::string injection_method = "fixed-magnitude-bipolar";
  double injection_interval_s = 0.0;
};

// INJECTION_COMMAND's methods by the names the command line takes: the DBC's labels in lower
// case with dashes (OFF aside: --inject-now asks for a measurement), so that the two never
// disagree.
std::vector<std::pair<std::string, protocol::InjectionMethod>> injection_methods() {
  std::vector<std::pair<std::string, protocol::InjectionMethod>> out;
  for (const protocol::ValueLabel& v : protocol::kInjectionMethodLabels) {
    if (v.value == static_cast<std::int64_t>(protocol::InjectionMethod::kOff)) {
      continue;
    }
    std::string name(v.label);
    for (char& c : name) {
      c = c == '_' ? '-' : static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    }
    out.emplace_back(std::move(name), static_cast<protocol::InjectionMethod>(v.value));
  }
  return out;
}

protocol::InjectionMethod injection_method(const std::string& name) {
  for (const auto& [option, method] : injection_methods()) {
    if (option == name) {
      return method;
    }
  }
  return protocol::InjectionMethod::kFixedMagnitudeBipolar;  // unreachable: the option checks its member
}

// A command line option's range is its signal's: a value the frame cannot carry is refused
// here, never sent saturated (docs/protocol.md: a saturated command must not be sent).
CLI::Validator signal_range(const protocol::SignalDef& signal) {
  return pmsm::cli::number_in_range(signal.minimum, signal.maximum);
}

int run_command(const CommandOptions& o) {
  hal::SocketCanConfig config;
  config.interface = o.iface;
  config.fd = false;  // the command frames are classic CAN
  // What the daemon says back about this node (THERMAL_ESTIMATE's calibration, RECEIVE_STATUS's
  // rejections), reported as it comes.
  const protocol::FilterSet heard = protocol::receive_filters(protocol::Role::kSupervisor, static_cast<protocol::NodeId>(o.node));
  config.filters = std::vector<hal::CanFilter>(heard.view().begin(), heard.view().end());
  hal::Status error;
  std::unique_ptr<hal::SocketCanBus> bus = hal::SocketCanBus::open(config, error);
  if (!bus) {
    std::fprintf(stderr, "pmsm-thermal command: cannot open the CAN bus: %s\n", error.message().c_str());
    return 1;
  }
  (void)hal::install_stop_signals();
  std::uint64_t failed_requests = 0;
  protocol::CommandSender sender(static_cast<protocol::NodeId>(o.node));
  hal::CanFrame frame{};
  auto send = [&](const auto& message) {
    const protocol::EncodeStatus e = sender.encode(message, frame);
    if (e != protocol::EncodeStatus::kOk) {
      // The options' ranges are the signals' (above), so this is a defect, not a user's value.
      std::fprintf(stderr, "pmsm-thermal command: frame 0x%03X not sent: a value is out of its signal's range\n",
                   frame.id);
      return false;
    }
    return bus->send(frame, std::chrono::milliseconds{10}) == hal::SendResult::kOk;
  };
  protocol::DriveCommand drive;
  drive.enable = o.mode != "disabled";
  drive.mode = o.mode == "torque" ? protocol::DriveMode::kTorque
               : o.mode == "speed" ? protocol::DriveMode::kSpeed
                                   : protocol::DriveMode::kDisabled;
  drive.speed_setpoint_rad_s = o.speed_rad_s.value_or(0.0);
  drive.torque_setpoint_Nm = o.torque_Nm.value_or(0.0);
  // A one-off request after a frame of its stream that asks for nothing (above), a few
  // milliseconds apart so that the two arrive in order.
  auto send_request = [&](auto synchronising, const auto& request) {
    bool ok = send(synchronising);
    std::this_thread::sleep_for(std::chrono::milliseconds{5});
    ok = send(request) && ok;
    if (!ok) {
      ++failed_requests;
    }
  };
  if (o.calibrate_at_C) {
    protocol::CalibrationCommand c;
    c.action = protocol::CalibrationAction::kStart;
    c.known_temp_C = *o.calibrate_at_C;
    protocol::CalibrationCommand nothing = c;
    nothing.action = protocol::CalibrationAction::kNone;
    send_request(nothing, c);
  }
  if (o.inject_now) {
    protocol::InjectionCommand i;
    // The frame sets the method and the interval too (amplitude 0: the drive keeps its own);
    // the synchronising frame sets the same.
    i.method = injection_method(o.injection_method);
    i.interval_s = o.injection_interval_s;
    protocol::InjectionCommand nothing = i;
    i.request_now = true;
    send_request(nothing, i);
  }
  const std::int64_t start = hal::monotonic_ns();
  std::uint64_t sent = 0;
  std::uint64_t failed = 0;
  // One synchronising frame a stream this run starts (DRIVE_COMMAND's first, and the requests'
  // frames that ask for nothing) may be refused for its counter; more is another sender.
  const int synchronising = 1 + (o.calibrate_at_C ? 1 : 0) + (o.inject_now ? 1 : 0);
  DaemonAnswers answers(o.node, o.calibrate_at_C.has_value(), stderr, synchronising);
  hal::ReceivedFrame received;
  while (!hal::stop_requested().load()) {
    if (o.duration_s && static_cast<double>(hal::monotonic_ns() - start) * 1e-9 >= *o.duration_s) {
      break;
    }
    if (send(drive)) {
      ++sent;
    } else {
      ++failed;
      answers.note_unsent_frame();
    }
    // The period in slices of at most 10 ms, reading what the daemon says meanwhile: Ctrl-C
    // sends the disabling frame at once, not after the rest of a long period.
    const std::int64_t next = hal::monotonic_ns() + static_cast<std::int64_t>(o.period_ms * 1e6);
    for (std::int64_t now = hal::monotonic_ns(); now < next && !hal::stop_requested().load(); now = hal::monotonic_ns()) {
      const auto slice = std::chrono::nanoseconds{std::min<std::int64_t>(next - now, 10'000'000)};
      if (bus->receive(received, slice) == hal::ReceiveStatus::kFrame) {
        answers.read(received.frame);
      } else {
        std::this_thread::sleep_for(std::chrono::nanoseconds{std::min<std::int64_t>(next - hal::monotonic_ns(), 1'000'000)});
      }
    }
  }
  const bool refused = answers.finish();
  drive.enable = false;
  drive.mode = protocol::DriveMode::kDisabled;
  const bool disabled = send(drive);
  std::fprintf(stderr, "pmsm-thermal command: %llu DRIVE_COMMAND frame(s) sent to node %d, %llu failed; %s\n",
               static_cast<unsigned long long>(sent), o.node, static_cast<unsigned long long>(failed),
               disabled ? "drive disabled"
                        : "the disabling frame was NOT sent: the drive stops by its command timeout "
                          "(supervisor.command_timeout_s), not by this tool");
  if (failed_requests > 0) {
    std::fprintf(stderr, "pmsm-thermal command: %llu one-off request(s) not sent (the transmit queue stayed full)\n",
                 static_cast<unsigned long long>(failed_requests));
  }
  if (refused) {
    std::fprintf(stderr, "pmsm-thermal command: the daemon refused what was asked (above): exit status 3\n");
  }
  // 1: a frame was not sent; 3: all sent, and the daemon refused some (scripts tell the two apart).
  return failed == 0 && failed_requests == 0 && disabled ? (refused ? 3 : 0) : 1;
}

}  // namespace

void register_command_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<CommandOptions>();
  CLI::App* cmd = app.add_subcommand("command", "Send E2E-protected drive commands to pmsm-thermald (the supervisor's role)");
  cmd->footer("Exit status: 0 every frame sent and nothing refused; 1 a frame could not be sent (the bus, a full transmit "
              "queue); 2 a bad command line; 3 every frame sent, but the daemon refused something asked of it (a "
              "calibration that ended other than DONE or was never seen, a command rejected, or more of this node's "
              "commands refused for their alive counter than this run's own synchronising frames: another supervisor "
              "sending to the node).");
  cmd->add_option("--iface", options->iface, "CAN interface")
      ->capture_default_str()
      ->check(pmsm::cli::text_rule(pmsm::hal::can_interface_name_problem, "NAME"));
  cmd->add_option("--node", options->node, "node id of the axis, 0..15")->check(pmsm::cli::integer_in_range(0, 15))->capture_default_str();
  cmd->add_option("--mode", options->mode, "speed, torque or disabled")
      ->check(CLI::IsMember({"speed", "torque", "disabled"}))
      ->capture_default_str();
  cmd->add_option("--speed", options->speed_rad_s, "speed set-point, mechanical rad/s")
      ->check(signal_range(protocol::drive_command::kSpeedSetpoint));
  cmd->add_option("--torque", options->torque_Nm, "torque set-point, Nm")->check(signal_range(protocol::drive_command::kTorqueSetpoint));
  cmd->add_option("--period-ms", options->period_ms,
                  "time between DRIVE_COMMAND frames, at most 250 ms (well below the daemon's command timeout, 0.5 s as shipped)")
      ->check(pmsm::cli::number_in_range(1.0, 250.0))
      ->capture_default_str();
  cmd->add_option("--duration", options->duration_s, "stop after this many seconds (default: until Ctrl-C)")
      ->check(pmsm::cli::number_in_range(0.0, 1e7));
  cmd->add_option("--calibrate-at", options->calibrate_at_C, "start an Rs0 calibration: the winding's temperature now, C")
      ->check(signal_range(protocol::calibration_command::kKnownTemp));
  CLI::Option* interval =
      cmd->add_option("--injection-interval", options->injection_interval_s,
                      "with --inject-now: the time between the drive's periodic injections from then on, s (0: only on "
                      "request); INJECTION_COMMAND sets it with every request")
          ->check(signal_range(protocol::injection_command::kInterval));
  CLI::Option* method =
      cmd->add_option("--injection-method", options->injection_method, "with --inject-now: the method from then on")
          ->check(CLI::IsMember([] {
            std::vector<std::string> names;
            for (const auto& entry : injection_methods()) names.push_back(entry.first);
            return names;
          }()));
  cmd->add_flag("--inject-now", options->inject_now,
                "request one injection event now (INJECTION_COMMAND; it also sets the drive's method and interval, "
                "so --injection-method and --injection-interval must be given)")
      ->needs(interval)
      ->needs(method);
  // A set-point belongs to its mode: torque mode without a torque would send 0 Nm unasked, and a
  // set-point for another mode would be sent and ignored without a word.
  cmd->callback([options, interval, method, &exit_code] {
    const CommandOptions& o = *options;
    const bool injection_set = interval->count() > 0 || method->count() > 0;
    const char* problem = o.mode == "torque" && !o.torque_Nm    ? "--mode torque needs --torque"
                          : o.mode == "speed" && !o.speed_rad_s ? "--mode speed needs --speed"
                          : o.mode != "torque" && o.torque_Nm   ? "--torque applies to --mode torque only"
                          : o.mode != "speed" && o.speed_rad_s  ? "--speed applies to --mode speed only"
                          : injection_set && !o.inject_now
                              ? "--injection-method and --injection-interval are sent with --inject-now only (the "
                                "INJECTION_COMMAND frame carries them): give --inject-now too"
                              : nullptr;
    if (problem != nullptr) {
      throw CLI::ValidationError("command", problem);
    }
    exit_code = run_command(o);
  });
}

}  // namespace pmsm::app
