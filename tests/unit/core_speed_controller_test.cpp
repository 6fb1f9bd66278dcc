#include <gtest/gtest.h>

#include <cmath>

#include "pmsm/core/speed_controller.hpp"

namespace pmsm::core {
namespace {

TEST(SpeedController, ReachesTheSetpointAgainstAConstantLoad) {
  SpeedControllerConfig config;
  config.bandwidth_rad_s = 50.0;
  SpeedController controller(config);
  const double j = 0.00841, load = 12.0, dt = config.period_s;
  double speed = 0.0;
  double max_speed = 0.0;
  for (int k = 0; k < 3000; ++k) {
    const double torque = controller.step(100.0, speed, 80.0);
    EXPECT_LE(std::abs(torque), 80.0);
    speed += (torque - load) / j * dt;
    max_speed = std::max(max_speed, speed);
  }
  EXPECT_NEAR(speed, 100.0, 0.05);
  EXPECT_LT(max_speed, 115.0);
}

TEST(SpeedController, RespectsTheTighterTorqueLimit) {
  SpeedController controller(SpeedControllerConfig{});
  for (int k = 0; k < 100; ++k) {
    EXPECT_LE(std::abs(controller.step(300.0, 0.0, 5.0)), 5.0);
  }
}

// While the current loop below cannot deliver (on its voltage limit), the integral does not
// grow the demand further; it may still shrink it, and the feed-forward passes through.
TEST(SpeedController, ASaturatedCurrentLoopHoldsTheIntegral) {
  SpeedController controller(SpeedControllerConfig{});
  const double first = controller.step(110.0, 100.0, 80.0, true);
  double last = first;
  for (int k = 0; k < 100; ++k) {
    last = controller.step(110.0, 100.0, 80.0, true);
  }
  EXPECT_NEAR(last, first, 1e-9) << "held: no growth away from zero torque";
  const double free = controller.step(110.0, 100.0, 80.0, false);
  EXPECT_GT(free, last) << "integrates again once the current loop follows";
  for (int k = 0; k < 100; ++k) {
    (void)controller.step(110.0, 100.0, 80.0, false);  // an integral well above Kp x 1 rad/s
  }
  const double back = controller.step(99.0, 100.0, 80.0, true);
  const double back_again = controller.step(99.0, 100.0, 80.0, true);
  ASSERT_GT(back_again, 0.0);
  EXPECT_LT(back_again, back) << "integration towards zero torque is never held";
  EXPECT_NEAR(controller.step(100.0, 100.0, 80.0, true, 5.0) - controller.step(100.0, 100.0, 80.0, true, 0.0), 5.0, 1e-9);
}

}  // namespace
}  // namespace pmsm::core
