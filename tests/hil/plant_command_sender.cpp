// plant_command_sender: a stand-in controller for the pmsm-plant HIL tests (NOT the daemon).
//
// On a CAN bus it receives this node's SENSOR_SAMPLE frames, converts the codes with the
// nominal front-end calibration of the plant profile (ADC ±range_A over `bits`, DC-bus
// full scale, encoder bits: the profile's values, as a commissioned controller would know
// them), and answers every sample with an INVERTER_COMMAND carrying the sample's sequence:
//
//   --law hold50   all duties at 50 % with the gates enabled: zero line-to-line voltage
//   --law dc       a fixed voltage vector along phase a (v_a = V, v_b = v_c = -V/2): at
//                  standstill a DC current of about V / Rs flows in a and -V/(2 Rs) in b, c
//   --law off      gates off (enable = 0)
//
// It stops after answering --periods distinct samples and prints a JSON summary on stdout
// (periods, wall time, periods/s, median and p99 of the cycle time between two new samples
// (one whole lockstep period: plant step, both transfers, this program), mean phase currents
// and DC-bus voltage over the second half). It waits with one ppoll() on the socket and
// reads the clock once per sample: under User-Mode Linux every system call costs ~15 us.
// Exit status: 0 done; 3 no sample within the timeout; 2 bad arguments or bus.
#include <poll.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/socketcan.hpp"
#include "pmsm/plant/config.hpp"

namespace {

namespace hal = pmsm::hal;
namespace protocol = pmsm::hal::protocol;
using std::chrono::nanoseconds;

struct Args {
  std::string iface;
  int node = 0;
  long periods = 2000;
  std::string law = "hold50";
  double voltage_V = 2.0;
  std::string config_path;
  long first_timeout_ms = 10000;  // the plant may still be starting (UML boots slowly)
  long timeout_ms = 2000;
};

[[noreturn]] void usage(const char* message) {
  std::fprintf(stderr,
               "plant_command_sender: %s\n"
               "usage: plant_command_sender [--iface vcan0] [--node 0] [--periods 2000] [--law hold50|dc|off]\n"
               "       [--voltage-V 2] [--config PROFILE.toml] [--first-timeout-ms 10000] [--timeout-ms 2000]\n",
               message);
  std::exit(2);
}

Args parse_args(int argc, char** argv) {
  Args a;
  const char* env_iface = std::getenv("PMSM_CAN_IFACE");
  a.iface = env_iface != nullptr && *env_iface != '\0' ? env_iface : "vcan0";
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (i + 1 >= argc) {
      usage(("missing value after " + flag).c_str());
    }
    const std::string value = argv[++i];
    char* end = nullptr;
    if (flag == "--iface") {
      a.iface = value;
    } else if (flag == "--node") {
      a.node = static_cast<int>(std::strtol(value.c_str(), &end, 10));
      if (*end != '\0' || a.node < 0 || a.node > protocol::kMaxNodeId) usage("--node: expected 0..15");
    } else if (flag == "--periods") {
      a.periods = std::strtol(value.c_str(), &end, 10);
      if (*end != '\0' || a.periods < 1) usage("--periods: expected a number >= 1");
    } else if (flag == "--law") {
      a.law = value;
      if (a.law != "hold50" && a.law != "dc" && a.law != "off") usage("--law: expected hold50, dc or off");
    } else if (flag == "--voltage-V") {
      a.voltage_V = std::strtod(value.c_str(), &end);
      if (*end != '\0' || !std::isfinite(a.voltage_V)) usage("--voltage-V: expected a number");
    } else if (flag == "--config") {
      a.config_path = value;
    } else if (flag == "--first-timeout-ms") {
      a.first_timeout_ms = std::strtol(value.c_str(), &end, 10);
      if (*end != '\0' || a.first_timeout_ms < 1) usage("--first-timeout-ms: expected a number >= 1");
    } else if (flag == "--timeout-ms") {
      a.timeout_ms = std::strtol(value.c_str(), &end, 10);
      if (*end != '\0' || a.timeout_ms < 1) usage("--timeout-ms: expected a number >= 1");
    } else {
      usage(("unknown option " + flag).c_str());
    }
  }
  return a;
}

// The controller's nominal view of the sensor front end (no gain or offset errors: it
// cannot know the plant's).
struct Calibration {
  double current_lsb_A;
  double dc_bus_lsb_V;

  explicit Calibration(const pmsm::plant::PlantConfig& c)
      : current_lsb_A(c.current_adc.range_A / std::ldexp(1.0, c.current_adc.bits - 1)),
        dc_bus_lsb_V(c.dc_bus_adc.full_scale_V / std::ldexp(1.0, c.dc_bus_adc.bits)) {}
};

std::uint16_t duty_code(double duty) {
  return static_cast<std::uint16_t>(std::lround(std::clamp(duty, 0.0, 1.0) * hal::kDutyFullScale));
}

double percentile_us(std::vector<std::int64_t>& values_ns, double fraction) {
  if (values_ns.empty()) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  const auto index = static_cast<std::size_t>(fraction * static_cast<double>(values_ns.size() - 1));
  std::nth_element(values_ns.begin(), values_ns.begin() + static_cast<std::ptrdiff_t>(index), values_ns.end());
  return static_cast<double>(values_ns[index]) * 1e-3;
}

}  // namespace

int main(int argc, char** argv) {
  const Args args = parse_args(argc, argv);
  pmsm::plant::PlantConfig config;  // the defaults equal profiles/reference.toml
  if (!args.config_path.empty()) {
    try {
      config = pmsm::plant::load_plant_config(args.config_path);
    } catch (const pmsm::plant::ConfigError& e) {
      std::fprintf(stderr, "plant_command_sender: %s\n", e.what());
      return 2;
    }
  }
  const Calibration cal(config);
  const auto node = static_cast<protocol::NodeId>(args.node);

  const protocol::FilterSet filters = protocol::receive_filters(protocol::Role::kDaemon, node);
  hal::SocketCanConfig bus_config;
  bus_config.interface = args.iface;
  bus_config.fd = true;
  bus_config.filters = std::vector<hal::CanFilter>(filters.view().begin(), filters.view().end());
  hal::Status error;
  const std::unique_ptr<hal::SocketCanBus> bus = hal::SocketCanBus::open(bus_config, error);
  if (!bus) {
    std::fprintf(stderr, "plant_command_sender: %s\n", error.message().c_str());
    return 2;
  }

  protocol::DaemonReceiver receiver(node);
  std::vector<std::int64_t> cycle_ns;
  cycle_ns.reserve(static_cast<std::size_t>(args.periods));
  std::optional<std::uint32_t> last_answered;
  std::int64_t last_sample_ns = 0;
  long answered = 0;
  long repeats_answered = 0;
  std::array<double, 3> current_sum_A{};
  double dc_bus_sum_V = 0.0;
  long averaged = 0;
  std::int64_t start_ns = 0;
  std::uint64_t send_failures = 0;

  hal::ReceivedFrame received;
  hal::CanFrame out;
  while (answered < args.periods) {
    const long wait_ms = last_answered ? args.timeout_ms : args.first_timeout_ms;
    pollfd p{bus->native_handle(), POLLIN, 0};
    const timespec ts{wait_ms / 1000, (wait_ms % 1000) * 1'000'000};
    const int ready = ::ppoll(&p, 1, &ts, nullptr);
    if (ready == 0) {
      std::fprintf(stderr,
                   "plant_command_sender: no SENSOR_SAMPLE for node %d on '%s' within %ld ms (answered %ld of %ld "
                   "periods)\n",
                   args.node, args.iface.c_str(), wait_ms, answered, args.periods);
      return 3;
    }
    const hal::ReceiveStatus status = bus->receive(received, nanoseconds{0});
    if (status == hal::ReceiveStatus::kTimeout || (ready < 0 && errno == EINTR)) {
      continue;
    }
    if (status != hal::ReceiveStatus::kFrame) {
      std::fprintf(stderr, "plant_command_sender: receive failed on '%s': %s\n", args.iface.c_str(),
                   hal::to_string(status));
      return 3;
    }
    const std::int64_t now_ns = hal::monotonic_ns();
    const protocol::DaemonInput input = receiver.receive(received.frame, nanoseconds{now_ns});
    const auto* sample = std::get_if<hal::SensorSample>(&input);
    if (sample == nullptr) {
      continue;
    }
    const bool repeat = last_answered && sample->sequence == *last_answered;
    if (!repeat && last_answered) {
      cycle_ns.push_back(now_ns - last_sample_ns);
    }
    if (!last_answered) {
      start_ns = now_ns;
    }

    hal::InverterCommand command;
    command.sequence = sample->sequence;
    command.enable = args.law != "off";
    const double vdc_V = std::max(sample->dc_bus_adc * cal.dc_bus_lsb_V, 1.0);
    if (args.law == "dc") {
      // Phase-to-neutral voltage = Vdc·(duty - mean duty): a at +V, b and c at -V/2.
      const double k = args.voltage_V / vdc_V;
      command.duty = {duty_code(0.5 + k), duty_code(0.5 - 0.5 * k), duty_code(0.5 - 0.5 * k)};
    } else {
      command.duty = {duty_code(0.5), duty_code(0.5), duty_code(0.5)};
    }
    (void)protocol::encode(command, node, out);
    const hal::SendResult sent = bus->send(out, std::chrono::milliseconds{2});
    if (sent != hal::SendResult::kOk) {
      ++send_failures;
    }
    if (repeat) {
      ++repeats_answered;  // the plant re-sent a sample: our command was lost or late
      continue;
    }
    last_answered = sample->sequence;
    last_sample_ns = now_ns;
    ++answered;
    if (answered > args.periods / 2) {
      for (std::size_t ph = 0; ph < 3; ++ph) {
        current_sum_A[ph] += sample->phase_current_adc[ph] * cal.current_lsb_A;
      }
      dc_bus_sum_V += sample->dc_bus_adc * cal.dc_bus_lsb_V;
      ++averaged;
    }
  }
  const double wall_s = static_cast<double>(hal::monotonic_ns() - start_ns) * 1e-9;
  const double n = averaged > 0 ? static_cast<double>(averaged) : std::numeric_limits<double>::quiet_NaN();
  const double median_us = percentile_us(cycle_ns, 0.5);
  const double p99_us = percentile_us(cycle_ns, 0.99);
  std::printf(
      "{\"periods\": %ld, \"law\": \"%s\", \"wall_s\": %.4f, \"periods_per_s\": %.1f, \"median_cycle_us\": %.1f, "
      "\"p99_cycle_us\": %.1f, \"repeats_answered\": %ld, \"send_failures\": %llu, \"ia_mean_A\": %.3f, "
      "\"ib_mean_A\": %.3f, \"ic_mean_A\": %.3f, \"vdc_mean_V\": %.2f, \"last_sequence\": %u}\n",
      answered, args.law.c_str(), wall_s, wall_s > 0.0 ? static_cast<double>(answered) / wall_s : 0.0, median_us,
      p99_us, repeats_answered, static_cast<unsigned long long>(send_failures), current_sum_A[0] / n,
      current_sum_A[1] / n, current_sum_A[2] / n, dc_bus_sum_V / n, last_answered.value_or(0));
  return 0;
}
