// The pmsm-plant process on a real (virtual) CAN bus (PMSM_CAN_IFACE, run through
// scripts/vcan-env): this test plays the controller and a bench monitor on the same bus.
//
// Under User-Mode Linux each run has its own bus and one slow CPU: real-time behaviour is
// checked through counters and status bits, never through timing. On a native shared vcan
// the plant runs with a node id derived from this process's id, and every socket here
// filters on that node.
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <memory>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/socketcan.hpp"

extern char** environ;

namespace pmsm::hal {
namespace {

using namespace std::chrono_literals;
using protocol::MessageType;

const std::string kPlant = PMSM_PLANT_EXE;
const std::string kProfile = std::string(PMSM_SOURCE_DIR) + "/plant-emulator/profiles/reference.toml";

std::string iface() {
  const char* name = std::getenv("PMSM_CAN_IFACE");
  return name != nullptr && *name != '\0' ? name : "vcan0";
}

protocol::NodeId test_node() {
  const char* mode = std::getenv("PMSM_VCAN_MODE");
  if (mode != nullptr && std::string(mode) == "uml") {
    return 0;  // a private bus
  }
  return static_cast<protocol::NodeId>(1 + ::getpid() % protocol::kMaxNodeId);
}

std::string read_file(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

std::optional<long long> summary_number(const std::string& log, const std::string& name) {
  std::smatch m;
  if (std::regex_search(log, m, std::regex(name + " ([0-9]+)"))) {
    return std::stoll(m[1].str());
  }
  return std::nullopt;
}

// pmsm-plant as a child process; stdout and stderr go to a file. SIGTERM on destruction.
class PlantProcess {
 public:
  explicit PlantProcess(std::vector<std::string> args) {
    char path[] = "/tmp/plant-hil-log-XXXXXX";
    const int fd = ::mkstemp(path);
    log_path_ = path;
    args.insert(args.begin(), kPlant);
    std::vector<char*> argv;
    for (std::string& a : args) {
      argv.push_back(a.data());
    }
    argv.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, fd, STDOUT_FILENO);
    posix_spawn_file_actions_adddup2(&actions, fd, STDERR_FILENO);
    posix_spawn_file_actions_addclose(&actions, fd);
    const int rc = ::posix_spawn(&pid_, kPlant.c_str(), &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    ::close(fd);
    if (rc != 0) {
      pid_ = -1;
      ADD_FAILURE() << "cannot start " << kPlant;
    }
  }
  ~PlantProcess() {
    (void)stop();
    std::remove(log_path_.c_str());
  }
  PlantProcess(const PlantProcess&) = delete;
  PlantProcess& operator=(const PlantProcess&) = delete;

  // SIGTERM (if still running) and the exit status (128 + signal if killed).
  int stop() {
    if (pid_ > 0 && !exit_code_) {
      ::kill(pid_, SIGTERM);
    }
    return wait(60s);
  }
  // Waits for the process to end by itself; -1 on timeout.
  int wait(std::chrono::milliseconds timeout) {
    if (exit_code_) {
      return *exit_code_;
    }
    if (pid_ <= 0) {
      return -1;
    }
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      int status = 0;
      const pid_t r = ::waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
        return *exit_code_;
      }
      if (std::chrono::steady_clock::now() > deadline) {
        return -1;
      }
      std::this_thread::sleep_for(5ms);
    }
  }
  [[nodiscard]] std::string log() const { return read_file(log_path_); }

 private:
  pid_t pid_ = -1;
  std::optional<int> exit_code_;
  std::string log_path_;
};

std::vector<std::string> plant_args(const std::string& mode, protocol::NodeId node, std::vector<std::string> extra = {},
                                    const std::string& interface = iface()) {
  std::vector<std::string> a{"--config", kProfile, "--iface", interface, "--node", std::to_string(node), "--mode", mode};
  a.insert(a.end(), extra.begin(), extra.end());
  return a;
}

// The controller's side: this node's SENSOR_SAMPLE frames; sends INVERTER_COMMAND.
class Controller {
 public:
  explicit Controller(protocol::NodeId node, const std::string& interface = iface()) : node_(node), receiver_(node) {
    const protocol::FilterSet filters = protocol::receive_filters(protocol::Role::kDaemon, node);
    bus_ = std::make_unique<SocketCanBus>(SocketCanConfig{
        .interface = interface,
        .fd = true,
        .filters = std::vector<CanFilter>(filters.view().begin(), filters.view().end()),
        .receive_buffer_bytes = 1 << 20});
  }

  std::optional<SensorSample> next_sample(std::chrono::nanoseconds timeout) {
    const std::int64_t deadline = monotonic_ns() + timeout.count();
    ReceivedFrame r;
    for (;;) {
      const std::int64_t left = deadline - monotonic_ns();
      if (left < 0 || bus_->receive(r, std::chrono::nanoseconds{left}) != ReceiveStatus::kFrame) {
        return std::nullopt;
      }
      const protocol::DaemonInput in = receiver_.receive(r.frame, std::chrono::nanoseconds{monotonic_ns()});
      if (const auto* s = std::get_if<SensorSample>(&in)) {
        return *s;
      }
    }
  }

  void drain() {
    while (next_sample(0ns)) {
    }
  }

  // Sends one command. After the interface went down and up, the socket reports the
  // pending ENETDOWN once: one retry covers that.
  SendResult send(std::uint32_t sequence, bool enable, std::array<double, 3> duty = {0.5, 0.5, 0.5}) {
    InverterCommand c;
    c.sequence = sequence;
    c.enable = enable;
    for (std::size_t i = 0; i < 3; ++i) {
      c.duty[i] = static_cast<std::uint16_t>(std::lround(duty[i] * kDutyFullScale));
    }
    CanFrame f;
    EXPECT_EQ(protocol::encode(c, node_, f), protocol::EncodeStatus::kOk);
    SendResult r = bus_->send(f, 10ms);
    if (r == SendResult::kInterfaceDown) {
      r = bus_->send(f, 10ms);
    }
    EXPECT_EQ(r, SendResult::kOk);
    return r;
  }

 private:
  protocol::NodeId node_;
  protocol::DaemonReceiver receiver_;
  std::unique_ptr<SocketCanBus> bus_;
};

// A bench monitor: this node's PLANT_STATUS frames.
class StatusMonitor {
 public:
  explicit StatusMonitor(protocol::NodeId node) : node_(node) {
    bus_ = std::make_unique<SocketCanBus>(SocketCanConfig{
        .interface = iface(),
        .fd = false,
        .filters = std::vector<CanFilter>{CanFilter::exact(protocol::can_id(MessageType::kPlantStatus, node), false)}});
  }
  std::optional<protocol::PlantStatus> next(std::chrono::nanoseconds timeout) {
    ReceivedFrame r;
    if (bus_->receive(r, timeout) != ReceiveStatus::kFrame) {
      return std::nullopt;
    }
    protocol::PlantStatus s;
    if (protocol::decode(r.frame, node_, s) != protocol::DecodeStatus::kOk) {
      ADD_FAILURE() << "undecodable PLANT_STATUS";
      return std::nullopt;
    }
    return s;
  }

 private:
  protocol::NodeId node_;
  std::unique_ptr<SocketCanBus> bus_;
};

TEST(plant_process_hil, MissingInterfaceIsNamed) {
  PlantProcess plant({"--config", kProfile, "--iface", "can7"});
  EXPECT_EQ(plant.wait(30s), 1);
  EXPECT_NE(plant.log().find("no such CAN interface 'can7'"), std::string::npos) << plant.log();
}

TEST(plant_process_hil, LockstepResendsAndIgnoresWrongSequences) {
  const protocol::NodeId node = test_node();
  Controller controller(node);
  PlantProcess plant(plant_args("lockstep", node, {"--resend-interval-ms", "20"}));

  // Nobody answers: sample 0 comes again and again, simulated time does not move.
  int zeros = 0;
  while (zeros < 3) {
    const std::optional<SensorSample> s = controller.next_sample(10s);
    ASSERT_TRUE(s) << "no SENSOR_SAMPLE from the plant; log:\n" << plant.log();
    ASSERT_EQ(s->sequence, 0U);
    ++zeros;
  }
  controller.send(0, true);
  std::optional<SensorSample> s;
  do {
    s = controller.next_sample(10s);
    ASSERT_TRUE(s);
  } while (s->sequence == 0);  // re-sends of 0 may still be queued
  ASSERT_EQ(s->sequence, 1U);

  controller.send(5, true);  // ahead of the plant
  controller.send(0, true);  // the one just applied, again
  // Only re-sends of sample 1 may come now.
  const std::int64_t until = monotonic_ns() + 200'000'000;
  while (monotonic_ns() < until) {
    if (const auto r = controller.next_sample(20ms)) {
      ASSERT_EQ(r->sequence, 1U);
    }
  }
  controller.send(1, true);
  do {
    s = controller.next_sample(10s);
    ASSERT_TRUE(s);
  } while (s->sequence == 1);
  ASSERT_EQ(s->sequence, 2U);
  controller.send(0, true);  // stale

  // The plant has read it before it is stopped: it re-sends sample 2 after each wait for a
  // command that brought none. Re-sends already queued here are drained; of those that come
  // after, the second ends a wait that began after the stale command had arrived (a fixed
  // pause of 100 ms was too short on a loaded host).
  controller.drain();
  for (int resends = 0; resends < 2;) {
    const std::optional<SensorSample> r = controller.next_sample(10s);
    ASSERT_TRUE(r) << "no re-send of sample 2; log:\n" << plant.log();
    ASSERT_EQ(r->sequence, 2U);
    ++resends;
  }
  EXPECT_EQ(plant.stop(), 0);
  const std::string log = plant.log();
  EXPECT_EQ(summary_number(log, "periods"), 2) << log;
  EXPECT_EQ(summary_number(log, "stale"), 1) << log;
  EXPECT_EQ(summary_number(log, "duplicate"), 1) << log;
  EXPECT_EQ(summary_number(log, "ahead"), 1) << log;
  EXPECT_GE(summary_number(log, "sample re-sends").value_or(0), 2) << log;
}

// The same configuration and the same command stream give the same samples, bit for bit.
std::vector<SensorSample> lockstep_run(protocol::NodeId node, int periods) {
  Controller controller(node);
  PlantProcess plant(plant_args("lockstep", node, {"--duration-s", std::to_string(periods * 1e-4)}));
  std::vector<SensorSample> samples;
  while (static_cast<int>(samples.size()) <= periods) {
    const std::optional<SensorSample> s = controller.next_sample(10s);
    if (!s) {
      ADD_FAILURE() << "no sample " << samples.size() << "; log:\n" << plant.log();
      return samples;
    }
    if (!samples.empty() && s->sequence == samples.back().sequence) {
      continue;  // a re-send
    }
    EXPECT_EQ(s->sequence, samples.size());
    samples.push_back(*s);
    if (static_cast<int>(samples.size()) > periods) {
      break;
    }
    // A command that depends on the sample: a crude proportional current loop on phase a
    // around a 20 A target, so that any difference in the samples changes the commands.
    const double ia_A = s->phase_current_adc[0] * (200.0 / 2048.0);
    const double k = std::clamp(0.002 * (20.0 - ia_A), -0.2, 0.2);
    controller.send(s->sequence, true, {0.5 + k, 0.5 - 0.5 * k, 0.5 - 0.5 * k});
  }
  EXPECT_EQ(plant.wait(30s), 0) << plant.log();
  return samples;
}

bool same(const SensorSample& a, const SensorSample& b) {
  return a.sequence == b.sequence && a.phase_current_adc == b.phase_current_adc &&
         a.encoder_count == b.encoder_count && a.dc_bus_adc == b.dc_bus_adc &&
         a.phase_voltage_adc == b.phase_voltage_adc && a.flags == b.flags;
}

TEST(plant_process_hil, LockstepIsDeterministic) {
  const protocol::NodeId node = test_node();
  const int periods = 300;
  const std::vector<SensorSample> first = lockstep_run(node, periods);
  const std::vector<SensorSample> second = lockstep_run(node, periods);
  ASSERT_EQ(first.size(), static_cast<std::size_t>(periods + 1));
  ASSERT_EQ(second.size(), first.size());
  int differing = 0;
  int with_current = 0;
  for (std::size_t i = 0; i < first.size(); ++i) {
    differing += same(first[i], second[i]) ? 0 : 1;
    with_current += std::abs(first[i].phase_current_adc[0]) > 50 ? 1 : 0;  // > 5 A
  }
  EXPECT_EQ(differing, 0);
  EXPECT_GT(with_current, periods / 2) << "the loop should drive a current";
}

// Real time, checked by behaviour only: no commands -> timeout and output off; commands ->
// output on; commands stop -> timeout again. Timing is not asserted (UML cannot keep 10 kHz).
TEST(plant_process_hil, RealtimeCommandTimeoutAndRecovery) {
  const protocol::NodeId node = test_node();
  Controller controller(node);
  StatusMonitor monitor(node);
  PlantProcess plant(plant_args("realtime", node, {"--truth-period-ms", "5", "--command-timeout-ms", "20"}));

  const auto wait_for_status = [&](auto predicate, std::chrono::seconds limit, bool answer) {
    std::optional<protocol::PlantStatus> last;
    const std::int64_t deadline = monotonic_ns() + std::chrono::nanoseconds{limit}.count();
    while (monotonic_ns() < deadline) {
      if (answer) {
        // Answer whatever samples are queued, then look at the status frames.
        while (const auto s = controller.next_sample(answer ? 1ms : 0ms)) {
          controller.send(s->sequence, true);
        }
      }
      while (const auto st = monitor.next(answer ? 0ms : 50ms)) {
        last = st;
        if (predicate(*st)) {
          return last;
        }
      }
    }
    ADD_FAILURE() << "status not reached; last: " << (last ? "tripped " + std::to_string(last->command_timeout_tripped) +
                                                                 " output " + std::to_string(last->output_enabled)
                                                           : std::string("none"))
                  << "\nlog:\n" << plant.log();
    return std::optional<protocol::PlantStatus>{};
  };

  // 1. No controller: the timeout trips, the output is off, periods are missing.
  const auto tripped = wait_for_status(
      [](const protocol::PlantStatus& s) { return s.command_timeout_tripped && s.missing_commands > 0; }, 20s, false);
  ASSERT_TRUE(tripped);
  EXPECT_EQ(tripped->mode, protocol::PlantMode::kRealtime);
  EXPECT_FALSE(tripped->output_enabled);
  const std::uint32_t missing_before = tripped->missing_commands;

  // 2. Commands arrive (late or on time, whatever the machine manages): output on again.
  controller.drain();
  const auto running = wait_for_status(
      [](const protocol::PlantStatus& s) { return !s.command_timeout_tripped && s.output_enabled; }, 30s, true);
  ASSERT_TRUE(running);
  EXPECT_GE(running->missing_commands, missing_before);

  // 3. Commands stop: the timeout trips again.
  const auto tripped_again = wait_for_status(
      [](const protocol::PlantStatus& s) { return s.command_timeout_tripped && !s.output_enabled; }, 20s, false);
  ASSERT_TRUE(tripped_again);
  EXPECT_GT(tripped_again->missing_commands, missing_before);

  EXPECT_EQ(plant.stop(), 0);
  const std::string log = plant.log();
  EXPECT_GE(summary_number(log, "command timeouts").value_or(0), 2) << log;
  EXPECT_GT(summary_number(log, "commands applied").value_or(0) + summary_number(log, "late").value_or(0), 0) << log;
  EXPECT_GT(summary_number(log, "missing").value_or(0), 0) << log;
  EXPECT_NE(log.find("stopped (signal)"), std::string::npos) << log;
}


bool run(const std::string& command) { return std::system((command + " >/dev/null 2>&1").c_str()) == 0; }

// A vcan of our own (needs CAP_NET_ADMIN: root in the UML guest), so that taking it down
// disturbs nobody else; removed after.
class ScratchVcan {
 public:
  ScratchVcan() : name_("pmsmpl" + std::to_string(::getpid() % 100000)) { created_ = run("ip link add dev " + name_ + " type vcan") && configure(); }
  ~ScratchVcan() { (void)run("ip link del dev " + name_); }
  ScratchVcan(const ScratchVcan&) = delete;
  ScratchVcan& operator=(const ScratchVcan&) = delete;
  bool configure() { return run("ip link set dev " + name_ + " mtu 72") && run("ip link set dev " + name_ + " up"); }
  bool set_up(bool up) { return run("ip link set dev " + name_ + (up ? " up" : " down")); }
  bool recreate() { return run("ip link del dev " + name_) && run("ip link add dev " + name_ + " type vcan") && configure(); }
  [[nodiscard]] bool created() const { return created_; }
  [[nodiscard]] const std::string& name() const { return name_; }

 private:
  std::string name_;
  bool created_ = false;
};

// Steps the plant once: answers the current sample (again for every re-send of it, as a
// controller does: a command sent while the plant was reopening its socket is lost) and
// returns the next sample's sequence.
std::optional<std::uint32_t> step_once(Controller& controller, std::uint32_t current) {
  if (controller.send(current, true) != SendResult::kOk) {
    return std::nullopt;
  }
  const std::int64_t deadline = monotonic_ns() + 10'000'000'000;
  while (monotonic_ns() < deadline) {
    const std::optional<SensorSample> s = controller.next_sample(1s);
    if (s && s->sequence != current) {
      return s->sequence;
    }
    if (s && controller.send(current, true) != SendResult::kOk) {
      return std::nullopt;
    }
  }
  return std::nullopt;
}

TEST(plant_process_hil, SurvivesTheInterfaceGoingDownAndBeingRecreated) {
  ScratchVcan vcan;
  if (!vcan.created()) {
    GTEST_SKIP() << "cannot create a vcan here (needs CAP_NET_ADMIN)";
  }
  auto controller = std::make_unique<Controller>(0, vcan.name());
  PlantProcess plant(plant_args("lockstep", 0, {"--resend-interval-ms", "20"}, vcan.name()));
  std::optional<SensorSample> first = controller->next_sample(10s);
  ASSERT_TRUE(first) << plant.log();
  ASSERT_EQ(step_once(*controller, 0), 1U);

  // Down and up again: the binding survives, the plant re-sends sample 1.
  ASSERT_TRUE(vcan.set_up(false));
  std::this_thread::sleep_for(300ms);
  ASSERT_TRUE(vcan.set_up(true));
  controller->drain();
  ASSERT_EQ(step_once(*controller, 1), 2U) << plant.log();

  // Deleted and created again: only a reopened socket works; the plant reopens its own.
  ASSERT_TRUE(vcan.recreate());
  controller = std::make_unique<Controller>(0, vcan.name());
  std::optional<SensorSample> again;
  again = controller->next_sample(10s);
  ASSERT_TRUE(again) << "no sample after the interface was recreated; log:\n" << plant.log();
  ASSERT_EQ(again->sequence, 2U);
  ASSERT_EQ(step_once(*controller, 2), 3U) << plant.log();

  EXPECT_EQ(plant.stop(), 0);
  const std::string log = plant.log();
  // Logged once per loss (or once for losses between two reports of the monitor).
  EXPECT_NE(log.find("down or gone"), std::string::npos) << log;
  EXPECT_NE(log.find("is back"), std::string::npos) << log;
  EXPECT_GE(summary_number(log, "interface losses").value_or(0), 1) << log;
  EXPECT_EQ(summary_number(log, "periods"), 3) << log;
}

}  // namespace
}  // namespace pmsm::hal
