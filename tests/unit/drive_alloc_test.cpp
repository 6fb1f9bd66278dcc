// DriveNode::step() — one control period, the 10 kHz hot path: front end, supervisor,
// controller and the period's publications — must not allocate, through calibration,
// injection events (pairs, fits, published estimates), the thermal filter, time-to-limit and
// a fault with its recovery. The global operator new is replaced for this test binary to count
// allocations; the plant around the controller is not counted.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>

#include "controller_config.hpp"
#include "drive_node.hpp"
#include "pmsm/plant/plant.hpp"

namespace {
std::atomic<long> g_allocations{0};
}  // namespace

void* operator new(std::size_t size) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) {
    return p;
  }
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t /*size*/) noexcept { std::free(p); }

namespace pmsm::app {
namespace {

TEST(drive_alloc, StepDoesNotAllocate) {
  ControllerConfig config = default_controller_config();
  config.drive.injection.interval_s = 0.3;
  config.drive.injection.first_event_s = 0.5;
  config.drive.calibration_injection.interval_s = 0.3;  // the next event follows the calibration soon
  plant::PlantConfig pc;
  pc.load.profile = plant::LoadProfile::constant_torque;
  pc.load.torque_Nm = 10.0;
  plant::Plant plant(pc);
  const long before_construction = g_allocations.load();
  DriveNode node(config, default_supervisor_config(config), PublishRates{});
  ASSERT_GT(g_allocations.load(), before_construction);  // the counter works; construction may allocate

  long in_step = 0;
  std::uint32_t published = 0;
  std::uint32_t pairs = 0;
  std::uint32_t events = 0;
  std::uint32_t thermal_frames = 0;
  std::uint32_t fault_reports = 0;
  for (int k = 0; k < 60000; ++k) {  // 6 s: calibration, then events under load
    const hal::SensorSample& sample = plant.sample();
    NodeInputs in;
    in.mode = core::DriveMode::kSpeed;
    in.speed_ref_rad_s = k < 2000 ? 0.0 : 100.0;
    in.start_calibration = k == 5000;
    in.clear_faults = k == 40100;
    // Ten periods without a sample: the sensor-timeout fault, then its recovery.
    const bool drop = k >= 40000 && k < 40010;
    const long before = g_allocations.load();
    const NodeStep& step = node.step(drop ? nullptr : &sample, in);
    in_step += g_allocations.load() - before;
    const core::DriveController& drive = node.controller();
    pairs += drive.last_pair() ? 1U : 0U;
    published += drive.last_estimate() ? 1U : 0U;
    events += drive.last_event() ? 1U : 0U;
    thermal_frames += step.publications.thermal ? 1U : 0U;
    fault_reports += static_cast<std::uint32_t>(step.publications.fault_count);
    if (step.command) {
      plant.step(*step.command);
    }
  }
  // The run exercised what it claims to.
  EXPECT_GT(pairs, 10U);
  EXPECT_GT(events, 8U) << "calibration and run-time events";
  EXPECT_GT(published, 2U) << "published estimates after the calibration";
  EXPECT_EQ(thermal_frames, 60U) << "THERMAL_ESTIMATE at 10 Hz over 6 s";
  EXPECT_GE(fault_reports, 2U) << "the sensor timeout became active and cleared";
  EXPECT_EQ(node.supervisor().counts()[static_cast<std::size_t>(core::FaultCode::kSensorTimeout)], 1U);
  EXPECT_EQ(in_step, 0);
}

}  // namespace
}  // namespace pmsm::app
