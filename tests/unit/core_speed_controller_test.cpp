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

}  // namespace
}  // namespace pmsm::core
