// PlantNode (the bus side of pmsm-plant) on the in-process bus: lockstep sequencing,
// re-sends and determinism, bench frames, rejected frames, interface loss, and the
// real-time command timeout. The same code runs on vcan in tests/hil/plant_process_hil_test.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <optional>
#include <thread>
#include <variant>
#include <vector>

#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/sim_bus.hpp"
#include "process/plant_node.hpp"

namespace pmsm::plant {
namespace {

using namespace std::chrono_literals;
namespace protocol = hal::protocol;

PlantConfig reference() {
  return load_plant_config(std::filesystem::path(PMSM_SOURCE_DIR) / "plant-emulator/profiles/reference.toml");
}

// A plant node running on its own thread over a SimBus, with a controller endpoint and a
// monitor endpoint that sees everything.
class Rig {
 public:
  explicit Rig(PlantNodeOptions options, const PlantConfig& config = reference()) {
    plant_bus_ = bus_.connect({.fd = true, .queue_capacity = 1024});
    EXPECT_TRUE(plant_bus_->set_filters(plant_receive_filters(options)).ok());
    controller_ = bus_.connect({.fd = true, .queue_capacity = 4096});
    const protocol::FilterSet daemon_filters = protocol::receive_filters(protocol::Role::kDaemon, options.node);
    EXPECT_TRUE(controller_->set_filters(daemon_filters.view()).ok());
    monitor_ = bus_.connect({.fd = true, .queue_capacity = 65536});
    node_.emplace(config, *plant_bus_, options);
    node_id_ = options.node;
  }
  ~Rig() { stop(); }
  Rig(const Rig&) = delete;
  Rig& operator=(const Rig&) = delete;

  void start() {
    thread_ = std::thread([this] {
      reason_ = node_->run(stop_);
      finished_ = true;
    });
  }
  // Whether run() has returned by itself (duration reached).
  [[nodiscard]] bool finished() const { return finished_; }
  StopReason stop() {
    stop_ = true;
    if (thread_.joinable()) {
      thread_.join();
    }
    return reason_;
  }
  std::optional<hal::SensorSample> sample(std::chrono::nanoseconds timeout) {
    hal::ReceivedFrame r;
    while (controller_->receive(r, timeout) == hal::ReceiveStatus::kFrame) {
      hal::SensorSample s;
      if (protocol::decode(r.frame, node_id_, s) == protocol::DecodeStatus::kOk) {
        return s;
      }
    }
    return std::nullopt;
  }
  void command(std::uint32_t sequence, bool enable = true, double duty_a = 0.5) {
    hal::InverterCommand c;
    c.sequence = sequence;
    c.enable = enable;
    c.duty = {static_cast<std::uint16_t>(std::lround(duty_a * hal::kDutyFullScale)), 32768, 32768};
    hal::CanFrame f;
    ASSERT_EQ(protocol::encode(c, node_id_, f), protocol::EncodeStatus::kOk);
    ASSERT_EQ(controller_->send(f), hal::SendResult::kOk);
  }
  void send_raw(const hal::CanFrame& f) { ASSERT_EQ(controller_->send(f), hal::SendResult::kOk); }

  std::vector<protocol::AnyDecoded> monitored() {
    std::vector<protocol::AnyDecoded> out;
    hal::ReceivedFrame r;
    while (monitor_->receive(r, 0ns) == hal::ReceiveStatus::kFrame) {
      protocol::AnyDecoded d;
      EXPECT_EQ(protocol::decode_any(r.frame, d), protocol::DecodeStatus::kOk);
      out.push_back(d);
    }
    return out;
  }

  PlantNode& node() { return *node_; }
  hal::SimBus& bus() { return bus_; }

 private:
  hal::SimBus bus_;
  std::unique_ptr<hal::CanBus> plant_bus_;
  std::unique_ptr<hal::CanBus> controller_;
  std::unique_ptr<hal::CanBus> monitor_;
  std::optional<PlantNode> node_;
  protocol::NodeId node_id_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<bool> finished_{false};
  StopReason reason_ = StopReason::kStopRequested;
  std::thread thread_;
};

template <class Predicate>
bool eventually(Predicate predicate, std::chrono::milliseconds limit = 5000ms) {
  const auto deadline = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < deadline) {
    if (predicate()) {
      return true;
    }
    std::this_thread::sleep_for(1ms);
  }
  return predicate();
}

PlantNodeOptions lockstep_options() {
  PlantNodeOptions o;
  o.node = 3;
  o.mode = RunMode::kLockstep;
  return o;
}

TEST(plant_node, LockstepStepsOnlyOnTheAwaitedSequence) {
  Rig rig(lockstep_options());
  rig.start();
  std::optional<hal::SensorSample> s = rig.sample(2s);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->sequence, 0U);

  rig.command(0);
  s = rig.sample(2s);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->sequence, 1U);

  rig.command(9);  // ahead
  rig.command(0);  // the one just applied
  EXPECT_FALSE(rig.sample(20ms)) << "the plant must not step on a wrong sequence";
  rig.command(1);
  s = rig.sample(2s);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->sequence, 2U);
  rig.command(0);  // stale

  ASSERT_TRUE(eventually([&] { return rig.node().stats().stale_commands == 1; }));
  rig.stop();
  const PlantNodeStats st = rig.node().stats();
  EXPECT_EQ(st.periods, 2U);
  EXPECT_EQ(st.commands_applied, 2U);
  EXPECT_EQ(st.future_commands, 1U);
  EXPECT_EQ(st.duplicate_commands, 1U);
  EXPECT_EQ(st.stale_commands, 1U);
  EXPECT_EQ(st.rejected_total(), 0U);
}


TEST(plant_node, LockstepResendsAnUnansweredSample) {
  PlantNodeOptions o = lockstep_options();
  o.resend_interval = 5ms;
  Rig rig(o);
  rig.start();
  int zeros = 0;
  while (zeros < 4) {
    const auto s = rig.sample(2s);
    ASSERT_TRUE(s);
    ASSERT_EQ(s->sequence, 0U);
    ++zeros;
  }
  EXPECT_TRUE(rig.node().stats().waiting_for_controller);
  EXPECT_EQ(rig.node().stats().periods, 0U) << "simulated time advances only with commands";
  rig.command(0);
  ASSERT_TRUE(eventually([&] { return rig.node().stats().periods == 1; }));
  EXPECT_FALSE(rig.node().stats().waiting_for_controller);
  EXPECT_GE(rig.node().stats().sample_resends, 3U);
}

// The process adds nothing to the physics: the sample stream over the bus equals the
// in-process plant's for the same command stream, bit for bit.
TEST(plant_node, LockstepMatchesTheInProcessPlant) {
  PlantNodeOptions o = lockstep_options();
  o.duration_s = 0.05;  // 500 periods
  Rig rig(o);
  Plant reference_plant(reference());
  rig.start();
  const hal::SensorSample* expected = &reference_plant.sample();
  for (std::uint32_t k = 0; k <= 500; ++k) {
    const auto s = rig.sample(2s);
    ASSERT_TRUE(s) << "period " << k;
    ASSERT_EQ(s->sequence, k);
    ASSERT_EQ(s->phase_current_adc, expected->phase_current_adc) << "period " << k;
    ASSERT_EQ(s->encoder_count, expected->encoder_count);
    ASSERT_EQ(s->dc_bus_adc, expected->dc_bus_adc);
    ASSERT_EQ(s->flags, expected->flags);
    if (k == 500) {
      break;
    }
    const double duty_a = 0.5 + 0.01 * std::sin(0.05 * k);
    rig.command(k, true, duty_a);
    hal::InverterCommand c;
    c.sequence = k;
    c.enable = true;
    c.duty = {static_cast<std::uint16_t>(std::lround(duty_a * hal::kDutyFullScale)), 32768, 32768};
    expected = &reference_plant.step(c);
  }
  ASSERT_TRUE(eventually([&] { return rig.finished(); }));
  EXPECT_EQ(rig.stop(), StopReason::kDuration);
  EXPECT_EQ(rig.node().plant().period(), 500U);
}

// With a thermal acceleration, the plant runs its thermal network at real time while the
// node's THERMAL_ESTIMATE says Calibrating, from the period after the frame arrived, exactly as
// an in-process plant switched at the same period; a malformed THERMAL_ESTIMATE is counted and
// changes nothing.
TEST(plant_node, ThermalTimeFollowsTheControllersCalibration) {
  PlantConfig config = reference();
  config.thermal.acceleration = 400.0;
  PlantNodeOptions o = lockstep_options();
  o.follow_calibration = true;
  o.duration_s = 0.1;  // 1,000 periods
  Rig rig(o, config);
  Plant switched(config);  // switched to real time for periods [300, 700)
  Plant accelerated(config);
  const auto thermal_estimate = [&](bool calibrating) {
    protocol::ThermalEstimate t;
    t.calibrating = calibrating;
    hal::CanFrame f;
    EXPECT_EQ(protocol::encode(t, 3, f), protocol::EncodeStatus::kOk);
    return f;
  };
  rig.start();
  for (std::uint32_t k = 0; k < 1000; ++k) {
    const auto s = rig.sample(2s);
    ASSERT_TRUE(s) << "period " << k;
    ASSERT_EQ(s->sequence, k);
    if (k == 300 || k == 700) {
      rig.send_raw(thermal_estimate(k == 300));
      switched.set_thermal_acceleration(k == 300 ? 1.0 : 400.0);
    }
    if (k == 500) {
      hal::CanFrame bad = thermal_estimate(false);
      bad.length = 4;  // THERMAL_ESTIMATE is 8 bytes: rejected, the calibration goes on
      rig.send_raw(bad);
    }
    if (k == 600) {
      ASSERT_TRUE(rig.node().stats().calibration_real_time);
    }
    // About 10 A of direct current in phase a: the winding warms.
    rig.command(k, true, 0.502);
    hal::InverterCommand c;
    c.sequence = k;
    c.enable = true;
    c.duty = {static_cast<std::uint16_t>(std::lround(0.502 * hal::kDutyFullScale)), 32768, 32768};
    switched.step(c);
    accelerated.step(c);
  }
  ASSERT_TRUE(eventually([&] { return rig.finished(); }));
  rig.stop();
  const PlantNodeStats st = rig.node().stats();
  EXPECT_EQ(st.calibrations_followed, 1U);
  EXPECT_FALSE(st.calibration_real_time);
  EXPECT_EQ(st.rejected[static_cast<std::size_t>(protocol::DecodeStatus::kWrongLength)], 1U);
  EXPECT_EQ(rig.node().plant().state().winding_temp_C, switched.state().winding_temp_C);
  EXPECT_GT(accelerated.state().winding_temp_C - 25.0, 1.5 * (switched.state().winding_temp_C - 25.0));
}

TEST(plant_node, BenchFramesEveryTruthPeriodOfSimulatedTime) {
  PlantNodeOptions o = lockstep_options();
  o.truth_period = 1ms;  // 10 periods
  o.duration_s = 0.01;   // 100 periods
  Rig rig(o);
  rig.start();
  for (std::uint32_t k = 0; k <= 100; ++k) {
    const auto s = rig.sample(2s);
    ASSERT_TRUE(s);
    ASSERT_EQ(s->sequence, k);
    if (k < 100) {
      rig.command(s->sequence);
    }
  }
  // The run ends by itself at the duration, after the last bench frames.
  ASSERT_TRUE(eventually([&] { return rig.finished(); }));
  EXPECT_EQ(rig.stop(), StopReason::kDuration);
  int thermal = 0;
  int electrical = 0;
  std::vector<protocol::PlantStatus> statuses;
  for (const protocol::AnyDecoded& d : rig.monitored()) {
    EXPECT_EQ(d.node, 3);
    thermal += d.type == protocol::MessageType::kTruthThermal ? 1 : 0;
    electrical += d.type == protocol::MessageType::kTruthElectrical ? 1 : 0;
    if (const auto* st = std::get_if<protocol::PlantStatus>(&d.message)) {
      statuses.push_back(*st);
    }
    if (const auto* t = std::get_if<protocol::TruthThermal>(&d.message)) {
      EXPECT_NEAR(t->winding_temp_C, 25.0, 0.1);
      EXPECT_NEAR(t->ambient_temp_C, 25.0, 1e-9);
    }
  }
  EXPECT_EQ(thermal, 11);  // k = 0, 10, ..., 100
  EXPECT_EQ(electrical, 11);
  ASSERT_EQ(statuses.size(), 11U);
  for (std::size_t i = 0; i < statuses.size(); ++i) {
    EXPECT_EQ(statuses[i].mode, protocol::PlantMode::kLockstep);
    EXPECT_NEAR(statuses[i].simulated_time_s, 0.001 * static_cast<double>(i), 0.006);
    EXPECT_FALSE(statuses[i].command_timeout_tripped);
  }
  EXPECT_TRUE(statuses.back().output_enabled);
}

TEST(plant_node, RejectedFramesAreCountedByReason) {
  Rig rig(lockstep_options());
  rig.start();
  ASSERT_TRUE(rig.sample(2s));
  hal::CanFrame f;
  f.id = protocol::can_id(protocol::MessageType::kInverterCommand, 3);
  f.fd = true;
  f.length = 8;  // INVERTER_COMMAND is 12 bytes
  rig.send_raw(f);
  f.fd = false;  // and a classic frame where CAN FD is defined
  rig.send_raw(f);
  ASSERT_TRUE(eventually([&] { return rig.node().stats().rejected_total() == 2; }));
  const PlantNodeStats st = rig.node().stats();
  EXPECT_EQ(st.rejected[static_cast<std::size_t>(protocol::DecodeStatus::kWrongLength)], 1U);
  EXPECT_EQ(st.rejected[static_cast<std::size_t>(protocol::DecodeStatus::kWrongFrameFormat)], 1U);
  EXPECT_EQ(st.periods, 0U);
}

TEST(plant_node, InterfaceLossIsSurvivedAndTheSocketReopened) {
  PlantNodeOptions o = lockstep_options();
  o.reopen_interval = 5ms;
  o.resend_interval = 10ms;
  Rig rig(o);
  rig.start();
  ASSERT_TRUE(rig.sample(2s));
  rig.bus().set_interface_up(false);
  ASSERT_TRUE(eventually([&] { return rig.node().stats().interface_down; }));
  rig.bus().set_interface_up(true);
  ASSERT_TRUE(eventually([&] { return !rig.node().stats().interface_down; }));
  EXPECT_GE(rig.node().stats().reopens, 1U);
  // Running again: the sample is re-sent and a command advances the plant.
  std::optional<hal::SensorSample> s = rig.sample(2s);
  ASSERT_TRUE(s);
  rig.command(s->sequence);
  ASSERT_TRUE(eventually([&] { return rig.node().stats().periods == 1; }));
}

// Real time on the host's clock (no priority): only behaviour is asserted, not timing.
TEST(plant_node, RealtimeTimeoutDisablesTheOutputAndCommandsReEnableIt) {
  PlantNodeOptions o;
  o.node = 5;
  o.mode = RunMode::kRealtime;
  o.command_timeout = 20ms;
  o.truth_period = 10ms;
  Rig rig(o);
  rig.start();

  // No controller: the timeout trips once and the gates stay off.
  ASSERT_TRUE(eventually([&] { return rig.node().stats().command_timeout_tripped; }));
  EXPECT_EQ(rig.node().stats().command_timeouts, 1U);
  EXPECT_FALSE(rig.node().stats().output_enabled);
  EXPECT_GT(rig.node().stats().missing_commands, 0U);

  // A controller answers every sample: the output follows its enable.
  std::atomic<bool> answering{true};
  std::thread controller([&] {
    while (answering) {
      if (const auto s = rig.sample(2ms)) {
        rig.command(s->sequence);
      }
    }
  });
  const bool enabled = eventually([&] {
    const PlantNodeStats st = rig.node().stats();
    return !st.command_timeout_tripped && st.output_enabled;
  });
  const std::uint64_t answered = rig.node().stats().commands_applied + rig.node().stats().late_commands;
  answering = false;
  controller.join();
  ASSERT_TRUE(enabled);
  EXPECT_GT(answered, 0U);

  // The controller stops: a second timeout, gates off.
  ASSERT_TRUE(eventually([&] {
    const PlantNodeStats st = rig.node().stats();
    return st.command_timeout_tripped && !st.output_enabled;
  }));
  EXPECT_GE(rig.node().stats().command_timeouts, 2U);
  rig.stop();
}


TEST(plant_node, RejectsAnInvalidNode) {
  hal::SimBus bus;
  auto endpoint = bus.connect({.fd = true});
  PlantNodeOptions o;
  o.node = 16;
  EXPECT_THROW(PlantNode(reference(), *endpoint, o), std::invalid_argument);
}

}  // namespace
}  // namespace pmsm::plant
