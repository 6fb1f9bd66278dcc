// DriveNode::step() — one control period, the 10 kHz hot path: front end, supervisor,
// controller and the period's publications — must not allocate, with every method and mode:
// fixed-magnitude and fixed-angle with both separations, DC, the no-injection baseline, the
// model alone, torque mode, derating and a calibration that times out; the first case also
// runs a fault with its recovery. Every allocator is counted (tests/support/alloc_counter.hpp:
// malloc and its family, so every operator new, aligned new and Eigen's dynamic matrices);
// the plant around the controller is not counted.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cstdlib>
#include <cstring>
#include <functional>
#include <new>
#include <string>

#include "alloc_counter.hpp"
#include "controller_config.hpp"
#include "drive_node.hpp"
#include "pmsm/plant/plant.hpp"

namespace pmsm::app {
namespace {

// The counter sees every way the code could allocate: malloc, new, aligned new, an Eigen
// dynamic matrix, libc's own strdup.
TEST(drive_alloc, TheCounterSeesEveryAllocator) {
  if (!test::allocation_counter_active()) {
    GTEST_SKIP() << "AddressSanitizer owns malloc: no allocation counter in this build";
  }
  auto counted = [](const std::function<void()>& f) {
    const long before = test::thread_allocations();
    f();
    return test::thread_allocations() - before;
  };
  EXPECT_EQ(counted([] {
              void* (*volatile allocate)(std::size_t) = &std::malloc;
              std::free(allocate(24));
            }), 1);
  EXPECT_EQ(counted([] {
              int* volatile p = new int(3);  // volatile: the pair must not be elided
              delete p;
            }), 1);
  EXPECT_EQ(counted([] {
              struct alignas(64) Line { char bytes[64]; };
              Line* volatile p = new Line{};
              delete p;
            }), 1);
  EXPECT_GE(counted([] {
              Eigen::MatrixXd m = Eigen::MatrixXd::Identity(5, 5);
              volatile double sink = m.sum();
              (void)sink;
            }), 1);
  EXPECT_EQ(counted([] { std::free(strdup("a string")); }), 1);
}

struct Case {
  std::string name;
  std::function<void(ControllerConfig&)> configure;
  core::DriveMode mode = core::DriveMode::kSpeed;
  int periods = 40000;
  bool fault_and_recovery = false;
};

struct Seen {
  std::uint32_t pairs = 0;
  std::uint32_t published = 0;
  std::uint32_t events = 0;
  std::uint32_t thermal_frames = 0;
  std::uint32_t calibration_edges = 0;  // each one also goes out at once (DriveNode::step)
  std::uint32_t fault_reports = 0;
  bool derating = false;
  bool calibration_failed = false;
};

class DriveAlloc : public ::testing::TestWithParam<Case> {};

TEST_P(DriveAlloc, StepDoesNotAllocate) {
  if (!test::allocation_counter_active()) {
    GTEST_SKIP() << "AddressSanitizer owns malloc: no allocation counter in this build";
  }
  const Case& c = GetParam();
  ControllerConfig config = default_controller_config();
  config.drive.injection.interval_s = 0.3;
  config.drive.injection.first_event_s = 0.5;
  config.drive.calibration_injection.interval_s = 0.3;  // the next event follows the calibration soon
  c.configure(config);
  finalize(config, "drive_alloc_test");
  plant::PlantConfig pc;
  pc.load.profile = plant::LoadProfile::constant_torque;
  pc.load.torque_Nm = 10.0;
  if (c.mode == core::DriveMode::kTorque) {
    // A torque command against a constant load leaves the shaft at the edge of its static
    // friction (2 Nm to spare), where whether it breaks away depends on the last digit of the
    // start: a fan settles it at a speed (12 Nm at 100 rad/s).
    pc.load.profile = plant::LoadProfile::fan;
    pc.load.torque_Nm = 0.0;
    pc.load.fan_k_Nm_s2 = 12.0 / (100.0 * 100.0);
  }
  plant::Plant plant(pc);
  const long before_construction = test::thread_allocations();
  DriveNode node(config, default_supervisor_config(config), PublishRates{});
  ASSERT_GT(test::thread_allocations(), before_construction);  // construction may allocate

  long in_step = 0;
  Seen seen;
  bool calibrating = false;
  for (int k = 0; k < c.periods; ++k) {
    const hal::SensorSample& sample = plant.sample();
    NodeInputs in;
    in.mode = c.mode;
    in.speed_ref_rad_s = k < 2000 ? 0.0 : 100.0;
    in.torque_ref_Nm = k < 2000 ? 0.0 : 12.0;
    in.start_calibration = k == 5000;
    const bool drop = c.fault_and_recovery && k >= 40000 && k < 40010;  // the sensor-timeout fault
    in.clear_faults = c.fault_and_recovery && k == 40100;              // and its recovery
    const long before = test::thread_allocations();
    const NodeStep& step = node.step(drop ? nullptr : &sample, in);
    in_step += test::thread_allocations() - before;
    const core::DriveController& drive = node.controller();
    seen.pairs += drive.last_pair() ? 1U : 0U;
    seen.published += drive.last_estimate() ? 1U : 0U;
    seen.events += drive.last_event() ? 1U : 0U;
    seen.thermal_frames += step.publications.thermal ? 1U : 0U;
    seen.calibration_edges += drive.telemetry().calibrating != calibrating ? 1U : 0U;
    calibrating = drive.telemetry().calibrating;
    seen.fault_reports += static_cast<std::uint32_t>(step.publications.fault_count);
    seen.derating = seen.derating || drive.telemetry().derating;
    seen.calibration_failed = seen.calibration_failed || drive.telemetry().calibration_failed;
    if (step.command) {
      plant.step(*step.command);
    }
  }
  EXPECT_EQ(in_step, 0) << c.name;

  // Each case exercised what it claims to.
  const bool injects = config.drive.estimator == core::EstimatorKind::kInjection;
  // THERMAL_ESTIMATE at 10 Hz, and at a calibration's start and end unless one falls on the cadence.
  EXPECT_GE(seen.thermal_frames, static_cast<std::uint32_t>(c.periods / 1000));
  EXPECT_LE(seen.thermal_frames, static_cast<std::uint32_t>(c.periods / 1000) + seen.calibration_edges);
  if (injects) {
    EXPECT_GT(seen.pairs, 5U) << c.name;
    EXPECT_GT(seen.events, 4U) << c.name << ": calibration and run-time events";
  }
  if (c.name == "fixed-magnitude-bipolar") {
    EXPECT_GT(seen.published, 2U) << "published estimates after the calibration";
    EXPECT_GE(seen.fault_reports, 2U) << "the sensor timeout became active and cleared";
    EXPECT_EQ(node.supervisor().counts()[static_cast<std::size_t>(core::FaultCode::kSensorTimeout)], 1U);
  }
  // The no-injection baseline adds every enabled period's sample to its regression (the hot
  // part); whether it publishes within 4 s depends on its excitation, not checked here.
  if (c.name == "derating") {
    EXPECT_TRUE(seen.derating);
  }
  if (c.name == "calibration-timeout") {
    EXPECT_TRUE(seen.calibration_failed);
  }
}

using core::InjectionMethod;
using core::Separation;

auto method(InjectionMethod m, Separation s) {
  return [m, s](ControllerConfig& c) {
    c.drive.injection.method = m;
    c.drive.injection.separation = s;
  };
}

INSTANTIATE_TEST_SUITE_P(
    EveryMethodAndMode, DriveAlloc,
    ::testing::Values(
        Case{"fixed-magnitude-bipolar", method(InjectionMethod::kFixedMagnitude, Separation::kBipolar),
             core::DriveMode::kSpeed, 60000, true},
        Case{"fixed-magnitude-unipolar", method(InjectionMethod::kFixedMagnitude, Separation::kUnipolar)},
        Case{"fixed-angle-bipolar", method(InjectionMethod::kFixedAngle, Separation::kBipolar)},
        Case{"fixed-angle-unipolar", method(InjectionMethod::kFixedAngle, Separation::kUnipolar)},
        Case{"dc", method(InjectionMethod::kDc, Separation::kBipolar)},
        Case{"no-injection-baseline", [](ControllerConfig& c) { c.drive.estimator = core::EstimatorKind::kNoInjection; }},
        Case{"model-only", [](ControllerConfig& c) { c.drive.estimator = core::EstimatorKind::kNone; }},
        Case{"torque-mode", method(InjectionMethod::kFixedMagnitude, Separation::kBipolar), core::DriveMode::kTorque},
        Case{"derating",
             [](ControllerConfig& c) {
               c.drive.derating.derate_start_C = 20.0;  // below the motor's own temperature: derating at once
               c.drive.derating.limit_C = 60.0;
             }},
        Case{"calibration-timeout", [](ControllerConfig& c) { c.drive.calibration_timeout_s = 0.4; }}),
    [](const ::testing::TestParamInfo<Case>& param) {
      std::string n = param.param.name;
      for (char& ch : n) ch = ch == '-' ? '_' : ch;
      return n;
    });

}  // namespace
}  // namespace pmsm::app
