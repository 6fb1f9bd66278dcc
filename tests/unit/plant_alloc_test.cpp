// Plant::step() must not allocate (the lockstep and real-time loops call it every period).
// Every allocator is counted (tests/support/alloc_counter.hpp: malloc and its family, so
// every operator new too).
#include <gtest/gtest.h>

#include "alloc_counter.hpp"
#include "pmsm/plant/plant.hpp"

namespace pmsm::plant {
namespace {

long allocations_during(Plant& plant, int periods, bool enable) {
  const long before = test::thread_allocations();
  for (int n = 0; n < periods; ++n) {
    hal::InverterCommand cmd;
    cmd.sequence = plant.period();
    cmd.enable = enable;
    cmd.duty = {34000, 32000, 31500};
    plant.step(cmd);
    plant.step_with_dq_voltage(1.0, 2.0);
  }
  return test::thread_allocations() - before;
}

TEST(plant_alloc, StepDoesNotAllocate) {
  if (!test::allocation_counter_active()) {
    GTEST_SKIP() << "AddressSanitizer owns malloc: no allocation counter in this build";
  }
  // Every feature that runs in the hot path: noise, voltage sensing, harmonics, saturation,
  // cogging, a torque table with ripple, the thermal network.
  PlantConfig c;
  c.phase_voltage_sensing.enabled = true;
  c.saturation.enabled = true;
  c.cogging.enabled = true;
  c.load.profile = LoadProfile::torque_cycle;
  c.load.points = {{0.0, 1.0}, {0.05, 3.0}, {0.1, -1.0}};
  const long before_construction = test::thread_allocations();
  Plant motoring(c);
  ASSERT_GT(test::thread_allocations(), before_construction);  // the counter works; construction may allocate
  EXPECT_EQ(allocations_during(motoring, 500, true), 0);

  // Gates off with the diodes rectifying behind an ideal dynamometer.
  c.load.profile = LoadProfile::speed_cycle;
  c.load.points = {{0.0, 450.0}, {1.0, 460.0}};
  Plant rectifying(c);
  EXPECT_EQ(allocations_during(rectifying, 500, false), 0);

  // Run-time setters keep their promise too.
  const long before = test::thread_allocations();
  rectifying.set_load_torque_Nm(2.0);
  rectifying.set_imposed_speed_rad_s(100.0);
  rectifying.set_ambient_C(40.0);
  EXPECT_EQ(test::thread_allocations() - before, 0);
}

}  // namespace
}  // namespace pmsm::plant
