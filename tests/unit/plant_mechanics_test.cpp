// Mechanics: static and Coulomb friction, load profiles, dynamometer modes, load ripple.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "pmsm/plant/plant.hpp"

namespace pmsm::plant {
namespace {

// Gates off throughout; sinusoidal EMF, no iron loss or viscous friction unless a test says
// otherwise, so the shaft feels friction and the load only.
PlantConfig shaft_config() {
  PlantConfig c;
  c.emf.shape = EmfShape::sinusoidal;
  c.iron_loss.enabled = false;
  c.mechanics.viscous_Nm_s_rad = 0.0;
  c.load.ripple_enabled = false;
  c.thermal.enabled = false;
  return c;
}

const hal::SensorSample& coast(Plant& plant) {
  hal::InverterCommand off;
  off.sequence = plant.period();
  return plant.step(off);
}

TEST(plant_mechanics, StictionHoldsWithoutChattering) {
  PlantConfig c = shaft_config();
  c.load.torque_Nm = 0.5;  // below the 0.908 N·m breakaway torque
  c.mechanics.initial_angle_rad = 0.3;
  Plant plant(c);
  for (int n = 0; n < 2000; ++n) {
    coast(plant);
    const PlantState s = plant.state();
    ASSERT_EQ(s.omega_m_rad_s, 0.0);
    ASSERT_DOUBLE_EQ(s.theta_m_rad, 0.3);
    ASSERT_TRUE(s.shaft_stuck);
  }
}

TEST(plant_mechanics, BreakawayAboveStaticFriction) {
  PlantConfig c = shaft_config();
  c.load.torque_Nm = 1.5;  // an active load pulling backwards
  Plant plant(c);
  for (int n = 0; n < 1000; ++n) {
    coast(plant);
  }
  // J·dω/dt = -(1.5 - 0.908) N·m.
  const double expected = -(1.5 - 0.908) / 0.00841 * 0.1;
  EXPECT_NEAR(plant.state().omega_m_rad_s, expected, 0.005 * std::abs(expected));
}

TEST(plant_mechanics, CoastDownStopsOnCoulombFrictionAndStays) {
  PlantConfig c = shaft_config();
  const double w0 = 50.0;
  c.mechanics.initial_speed_rad_s = w0;
  Plant plant(c);
  // Constant deceleration Tc/J: stop after w0·J/Tc, having turned w0²·J/(2·Tc).
  const double t_stop = w0 * 0.00841 / 0.908;
  const double travel = w0 * w0 * 0.00841 / (2.0 * 0.908);
  double theta_unwrapped = 0.0;
  double theta_prev = plant.state().theta_m_rad;
  double first_zero_s = -1.0;
  for (int n = 0; n < 6000; ++n) {
    coast(plant);
    const PlantState s = plant.state();
    double d = s.theta_m_rad - theta_prev;
    if (d < -3.0) {
      d += 2.0 * std::numbers::pi;
    }
    theta_unwrapped += d;
    theta_prev = s.theta_m_rad;
    if (s.omega_m_rad_s == 0.0 && first_zero_s < 0.0) {
      first_zero_s = s.time_s;
    }
    if (first_zero_s >= 0.0) {
      ASSERT_EQ(s.omega_m_rad_s, 0.0) << "restarted at " << s.time_s;
    } else {
      ASSERT_GT(s.omega_m_rad_s, 0.0);  // never overshoots into reverse
    }
  }
  EXPECT_NEAR(first_zero_s, t_stop, 1.01e-4);
  EXPECT_NEAR(theta_unwrapped, travel, 0.001 * travel);
}

TEST(plant_mechanics, TorqueSteps) {
  PlantConfig c = shaft_config();
  c.mechanics.inertia_kg_m2 = 100.0;  // the shaft hardly moves; we read the load torque
  c.load.profile = LoadProfile::torque_steps;
  c.load.torque_Nm = 1.0;
  c.load.points = {{0.01, 5.0}, {0.02, -3.0}};
  Plant plant(c);
  for (int n = 0; n < 300; ++n) {
    coast(plant);
    const double t = plant.time_s();
    const double expected = t < 0.01 ? 1.0 : (t < 0.02 ? 5.0 : -3.0);
    ASSERT_NEAR(static_cast<double>(plant.truth().load_torque_Nm), expected, 1e-5) << t;
  }
}

TEST(plant_mechanics, FanLoadFollowsSpeedSquared) {
  PlantConfig c = shaft_config();
  c.mechanics.initial_speed_rad_s = 200.0;
  c.load.profile = LoadProfile::fan;
  c.load.fan_k_Nm_s2 = 2e-4;
  Plant plant(c);
  for (int n = 0; n < 500; ++n) {
    coast(plant);
    const PlantState s = plant.state();
    ASSERT_NEAR(s.load_torque_Nm, 2e-4 * s.omega_m_rad_s * s.omega_m_rad_s, 1e-9);
  }
  // Fan plus friction slows it: J·dω/dt = -(Tc + k·ω²).
  EXPECT_LT(plant.state().omega_m_rad_s, 200.0);
}

TEST(plant_mechanics, TorqueCycleInterpolates) {
  PlantConfig c = shaft_config();
  c.mechanics.inertia_kg_m2 = 100.0;
  c.load.profile = LoadProfile::torque_cycle;
  c.load.points = {{0.0, 0.0}, {0.02, 10.0}, {0.03, 10.0}};
  Plant plant(c);
  for (int n = 0; n < 400; ++n) {
    coast(plant);
    const double t = plant.time_s();
    const double expected = std::min(t, 0.02) / 0.02 * 10.0;
    ASSERT_NEAR(static_cast<double>(plant.truth().load_torque_Nm), expected, 1e-4) << t;
  }
}

TEST(plant_mechanics, IdealDynamometerImposesSpeedProfile) {
  PlantConfig c = shaft_config();
  c.load.profile = LoadProfile::speed_cycle;
  c.load.points = {{0.0, 0.0}, {0.1, 100.0}, {0.2, 100.0}};
  Plant plant(c);
  double theta_expected = 0.0;
  for (int n = 0; n < 2000; ++n) {
    coast(plant);
    const double t = plant.time_s();
    const double w = std::min(t, 0.1) * 1000.0;
    ASSERT_NEAR(static_cast<double>(plant.truth().speed_rad_s), w, 1e-3);
    // The dynamometer supplies J·dω/dt plus friction (no current, no cogging).
    const double accel = t < 0.1 ? 1000.0 : 0.0;
    if (n > 0 && std::abs(t - 0.1) > 2e-4) {
      ASSERT_NEAR(plant.state().load_torque_Nm, -(0.00841 * accel + 0.908), 1e-6) << t;
    }
  }
  // θ = ∫ω dt: 0.5·1000·0.1² + 100·0.1 = 15 rad.
  theta_expected = std::fmod(15.0, 2.0 * std::numbers::pi);
  EXPECT_NEAR(plant.state().theta_m_rad, theta_expected, 1e-6);
}

TEST(plant_mechanics, PiDynamometerTracksSpeed) {
  PlantConfig c = shaft_config();
  c.load.profile = LoadProfile::speed_cycle;
  c.load.speed_rad_s = 100.0;
  c.load.dyno_bandwidth_Hz = 20.0;
  Plant plant(c);
  for (int n = 0; n < 5000; ++n) {
    coast(plant);
  }
  EXPECT_NEAR(plant.state().omega_m_rad_s, 100.0, 0.05);
  // In steady state it holds the friction: T_load = -Tc.
  EXPECT_NEAR(plant.state().load_torque_Nm, -0.908, 0.01);
}

TEST(plant_mechanics, LoadRippleAtMechanicalOrder) {
  PlantConfig c = shaft_config();
  c.mechanics.inertia_kg_m2 = 1.0;
  c.mechanics.initial_speed_rad_s = 100.0;
  c.mechanics.coulomb_Nm = 0.0;
  c.mechanics.breakaway_Nm = 0.0;
  c.load.torque_Nm = 10.0;
  c.load.ripple_enabled = true;
  c.load.ripple_fraction = 0.02;
  c.load.ripple_order = 2.0;
  Plant plant(c);
  double lo = 1e9;
  double hi = -1e9;
  for (int n = 0; n < 700; ++n) {  // more than one revolution at 100 rad/s (628 periods)
    coast(plant);
    const PlantState s = plant.state();
    ASSERT_NEAR(s.load_torque_Nm, 10.0 * (1.0 + 0.02 * std::sin(2.0 * s.theta_m_rad)), 1e-9);
    lo = std::min(lo, s.load_torque_Nm);
    hi = std::max(hi, s.load_torque_Nm);
  }
  EXPECT_NEAR(hi - lo, 0.4, 0.005);
}

}  // namespace
}  // namespace pmsm::plant
