// DriveController::step() — one control period, the 10 kHz hot path — must not allocate,
// through calibration, injection events (pairs, fits, published estimates), the thermal
// filter and time-to-limit. The global operator new is replaced for this test binary to count
// allocations; the plant around the controller is not counted.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>

#include "controller_config.hpp"
#include "pmsm/plant/plant.hpp"
#include "sensor_frontend.hpp"

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
  core::DriveController drive(config.drive);
  SensorFrontend frontend(config.sensors, config.drive.period_s);
  ASSERT_GT(g_allocations.load(), before_construction);  // the counter works; construction may allocate

  long in_step = 0;
  std::uint32_t published = 0;
  std::uint32_t pairs = 0;
  std::uint32_t events = 0;
  for (int k = 0; k < 60000; ++k) {  // 6 s: calibration, then events under load
    const hal::SensorSample& sample = plant.sample();
    const core::DriveInput in = frontend.convert(sample);
    core::DriveCommand cmd;
    cmd.mode = core::DriveMode::kSpeed;
    cmd.speed_ref_rad_s = k < 2000 ? 0.0 : 100.0;
    const long before = g_allocations.load();
    if (k == 5000) {
      drive.start_calibration(25.0);
    }
    const core::DriveOutput& out = drive.step(in, cmd);
    in_step += g_allocations.load() - before;
    pairs += drive.last_pair() ? 1U : 0U;
    published += drive.last_estimate() ? 1U : 0U;
    events += drive.last_event() ? 1U : 0U;
    plant.step(SensorFrontend::command(out, sample.sequence));
  }
  // The run exercised what it claims to.
  EXPECT_GT(pairs, 10U);
  EXPECT_GT(events, 8U) << "calibration and run-time events";
  EXPECT_GT(published, 2U) << "published estimates after the calibration";
  EXPECT_EQ(in_step, 0);
}

}  // namespace
}  // namespace pmsm::app
