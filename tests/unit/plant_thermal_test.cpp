// Thermal network against its analytic response, computed here from the network matrices
// by an eigen-decomposition (the library uses a matrix exponential instead).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>

#include "pmsm/plant/plant.hpp"
#include "pmsm/plant/thermal.hpp"

namespace pmsm::plant {
namespace {

// The network of docs/plant.md, built from the configuration by hand:
// C·dT/dt = -G·T + g_amb·T_amb + P, nodes winding, housing, rotor.
struct Network {
  Eigen::Vector3d c;
  Eigen::Matrix3d g;
  Eigen::Vector3d g_amb;

  explicit Network(const ThermalConfig& t) {
    c << t.winding_capacity_J_K, t.housing_capacity_J_K, t.rotor_capacity_J_K;
    const double wh = 1.0 / t.winding_to_housing_K_W;
    const double ha = 1.0 / t.housing_to_ambient_K_W;
    const double rh = 1.0 / t.rotor_to_housing_K_W;
    const double ra = 1.0 / t.rotor_to_ambient_K_W;
    g << wh, -wh, 0.0,  //
        -wh, wh + ha + rh, -rh,  //
        0.0, -rh, rh + ra;
    g_amb << 0.0, ha, ra;
  }

  // Eigenvalues (1/s, positive) and the mode shapes of C^-1·G through the symmetric
  // matrix C^-1/2·G·C^-1/2.
  [[nodiscard]] Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> modes() const {
    const Eigen::Matrix3d s = c.cwiseSqrt().cwiseInverse().asDiagonal() * g *
                              c.cwiseSqrt().cwiseInverse().asDiagonal();
    return Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(s);
  }

  // T(t) for constant losses p and ambient, from t0_C at t = 0.
  [[nodiscard]] Eigen::Vector3d response(const Eigen::Vector3d& t0_C, const Eigen::Vector3d& p_W,
                                         double ambient_C, double t_s) const {
    const Eigen::Vector3d t_ss = g.ldlt().solve(p_W + g_amb * ambient_C);
    const auto es = modes();
    const Eigen::Matrix3d q = es.eigenvectors();
    const Eigen::Vector3d decay = (-es.eigenvalues() * t_s).array().exp();
    const Eigen::Matrix3d half = c.cwiseSqrt().asDiagonal();
    const Eigen::Matrix3d half_inv = c.cwiseSqrt().cwiseInverse().asDiagonal();
    // exp(-C^-1·G·t) = C^-1/2·Q·exp(-Λt)·Qᵀ·C^1/2.
    const Eigen::Matrix3d e = half_inv * q * decay.asDiagonal() * q.transpose() * half;
    return t_ss + e * (t0_C - t_ss);
  }
};

TEST(plant_thermal, DominantTimeConstantIsTableI) {
  const ThermalConfig t;
  const Network net(t);
  const double tau_s = 1.0 / net.modes().eigenvalues().minCoeff();
  EXPECT_NEAR(tau_s, 2880.0, 0.02 * 2880.0);
  // The library's own figure agrees (for diagnostics).
  EXPECT_NEAR(ThermalNetwork(t, 1.0).dominant_time_constant_s(), tau_s, 1e-6 * tau_s);
}

TEST(plant_thermal, LossStepMatchesAnalyticResponse) {
  const ThermalConfig t;
  const Network net(t);
  const double step_s = 10.0;
  ThermalNetwork sim(t, step_s);
  const ThermalNetwork::Vector loss{400.0, 250.0, 30.0};
  const Eigen::Vector3d p(loss[0], loss[1], loss[2]);
  const Eigen::Vector3d t0(25.0, 25.0, 25.0);
  std::vector<double> late_t;
  std::vector<double> late_log;
  const Eigen::Vector3d t_ss = net.g.ldlt().solve(p + net.g_amb * 25.0);
  for (int n = 1; n <= 2000; ++n) {
    sim.step(loss, 25.0);
    const double time_s = n * step_s;
    const Eigen::Vector3d expected = net.response(t0, p, 25.0, time_s);
    for (int i = 0; i < 3; ++i) {
      const double rise = expected(i) - 25.0;
      ASSERT_NEAR(sim.temperatures_C()[static_cast<std::size_t>(i)], expected(i), 0.01 * rise)
          << "node " << i << " at " << time_s << " s";
    }
    if (time_s >= 8000.0 && time_s <= 16000.0) {
      late_t.push_back(time_s);
      late_log.push_back(std::log(t_ss(0) - sim.temperatures_C()[0]));
    }
  }
  // The measured winding response decays with the dominant time constant: slope of
  // ln(T_ss - T) by least squares.
  double mt = 0.0;
  double ml = 0.0;
  for (std::size_t i = 0; i < late_t.size(); ++i) {
    mt += late_t[i];
    ml += late_log[i];
  }
  mt /= static_cast<double>(late_t.size());
  ml /= static_cast<double>(late_t.size());
  double num = 0.0;
  double den = 0.0;
  for (std::size_t i = 0; i < late_t.size(); ++i) {
    num += (late_t[i] - mt) * (late_log[i] - ml);
    den += (late_t[i] - mt) * (late_t[i] - mt);
  }
  const double tau_measured_s = -den / num;
  EXPECT_NEAR(tau_measured_s, 2880.0, 0.02 * 2880.0);
}

PlantConfig heating_config(double alpha_per_C) {
  PlantConfig c;
  c.emf.shape = EmfShape::sinusoidal;
  c.iron_loss.enabled = false;
  c.motor.alpha_per_C = alpha_per_C;
  c.thermal.acceleration = 1000.0;
  c.load.profile = LoadProfile::speed_cycle;  // shaft held at standstill by the dynamometer
  c.load.speed_rad_s = 0.0;
  return c;
}

TEST(plant_thermal, AcceleratedHeatUpFollowsNetwork) {
  // 50 A d-axis current at standstill: about 500 W copper loss in the winding. With
  // alpha = 0 the loss is constant, so after the electrical transient the temperatures
  // must follow the network's analytic step response, 1000 times faster.
  const PlantConfig c = heating_config(0.0);
  Plant plant(c);
  const double vd = 0.133 * 50.0;
  for (int i = 0; i < 5000; ++i) {  // 0.5 s: the current settles (L/R = 41 ms)
    plant.step_with_dq_voltage(vd, 0.0);
  }
  const PlantState s1 = plant.state();
  const Eigen::Vector3d t1(s1.winding_temp_C, s1.housing_temp_C, s1.magnet_temp_C);
  const double p_cu = 1.5 * 0.133 * (s1.id_A * s1.id_A + s1.iq_A * s1.iq_A);
  for (int i = 0; i < 25000; ++i) {  // 2.5 s electrical = 2500 s thermal
    plant.step_with_dq_voltage(vd, 0.0);
  }
  const PlantState s2 = plant.state();
  const Network net(c.thermal);
  const Eigen::Vector3d expected =
      net.response(t1, Eigen::Vector3d(p_cu, 0.0, 0.0), 25.0, (s2.time_s - s1.time_s) * 1000.0);
  EXPECT_NEAR(s2.winding_temp_C, expected(0), 0.01 * (expected(0) - 25.0));
  EXPECT_NEAR(s2.housing_temp_C, expected(1), 0.01 * (expected(1) - 25.0));
  EXPECT_NEAR(s2.magnet_temp_C, expected(2), 0.01 * (expected(2) - 25.0));
  EXPECT_GT(s2.winding_temp_C, 60.0);  // a real heat-up
  const double p_cu2 = 1.5 * 0.133 * (s2.id_A * s2.id_A + s2.iq_A * s2.iq_A);
  EXPECT_NEAR(p_cu2, p_cu, 0.001 * p_cu);  // the loss really was constant
  EXPECT_NEAR(static_cast<double>(plant.truth().copper_loss_W), p_cu2, 1e-4 * p_cu2);
}

TEST(plant_thermal, AShaftFanLeavesItsStandstillShareAtRest) {
  // A self-ventilated machine at standstill: its housing sheds what natural convection alone
  // passes, fan_standstill_share of the path housing_to_ambient_K_W holds at the fan's speed.
  // The heat-up of AcceleratedHeatUpFollowsNetwork must follow the network with that path,
  // within 1 % of the rise, and lie well away from the network without the fan (the plant adds
  // the fan's part as a heat flow at each step's start temperature).
  PlantConfig c = heating_config(0.0);
  c.thermal.fan_speed_rad_s = 314.0;
  c.thermal.fan_standstill_share = 0.35;
  Plant plant(c);
  const double vd = 0.133 * 50.0;
  for (int i = 0; i < 5000; ++i) {
    plant.step_with_dq_voltage(vd, 0.0);
  }
  const PlantState s1 = plant.state();
  const Eigen::Vector3d t1(s1.winding_temp_C, s1.housing_temp_C, s1.magnet_temp_C);
  const double p_cu = 1.5 * 0.133 * (s1.id_A * s1.id_A + s1.iq_A * s1.iq_A);
  for (int i = 0; i < 25000; ++i) {
    plant.step_with_dq_voltage(vd, 0.0);
  }
  const PlantState s2 = plant.state();
  const double t_s = (s2.time_s - s1.time_s) * 1000.0;
  ThermalConfig at_rest = c.thermal;
  at_rest.housing_to_ambient_K_W = c.thermal.housing_to_ambient_K_W / 0.35;
  const Eigen::Vector3d expected = Network(at_rest).response(t1, Eigen::Vector3d(p_cu, 0.0, 0.0), 25.0, t_s);
  EXPECT_NEAR(s2.winding_temp_C, expected(0), 0.01 * (expected(0) - 25.0));
  EXPECT_NEAR(s2.housing_temp_C, expected(1), 0.01 * (expected(1) - 25.0));
  EXPECT_NEAR(s2.magnet_temp_C, expected(2), 0.01 * (expected(2) - 25.0));
  const Eigen::Vector3d without = Network(c.thermal).response(t1, Eigen::Vector3d(p_cu, 0.0, 0.0), 25.0, t_s);
  EXPECT_GT(s2.housing_temp_C - without(1), 0.2 * (without(1) - 25.0));  // the fan's absence shows
}

TEST(plant_thermal, AShaftFanAtSpeedCoolsAsItsShareSays) {
  // The shaft held at 100 rad/s by the dynamometer (the reference's fan speed 314 rad/s, share
  // 0.35 at rest): the housing's path is 0.35 + 0.65 (100 / 314)^0.8 of the fan speed's. A
  // constant d current heats the winding (no iron loss, alpha 0: the losses hold); the friction's
  // heat enters the housing. The heat-up must follow the network with that path, and not the
  // ones at rest or at the fan's speed.
  PlantConfig c = heating_config(0.0);
  c.load.speed_rad_s = 100.0;
  c.thermal.fan_speed_rad_s = 314.0;
  c.thermal.fan_standstill_share = 0.35;
  c.motor.magnet_temp_coefficient_per_C = 0.0;  // the magnets' flux, and so the current, hold
  Plant plant(c);
  // The winding shorted (no voltage): the EMF drives a constant current through it.
  const double vd = 0.0;
  const double vq = 0.0;
  for (int i = 0; i < 5000; ++i) {
    plant.step_with_dq_voltage(vd, vq);
  }
  const PlantState s1 = plant.state();
  const Eigen::Vector3d t1(s1.winding_temp_C, s1.housing_temp_C, s1.magnet_temp_C);
  const double p_w = s1.copper_loss_W;
  const double p_h = c.thermal.friction_heat_fraction * s1.friction_loss_W;
  ASSERT_GT(p_w, 100.0);
  for (int i = 0; i < 25000; ++i) {
    plant.step_with_dq_voltage(vd, vq);
  }
  const PlantState s2 = plant.state();
  EXPECT_NEAR(s2.copper_loss_W, p_w, 0.01 * p_w) << "a constant loss";
  const double t_s = (s2.time_s - s1.time_s) * 1000.0;
  const double share = 0.35 + 0.65 * std::pow(100.0 / 314.0, 0.8);
  EXPECT_DOUBLE_EQ(ThermalNetwork::fan_share(c.thermal, 100.0), share);
  const auto response = [&](double s) {
    ThermalConfig path = c.thermal;
    path.housing_to_ambient_K_W = c.thermal.housing_to_ambient_K_W / s;
    return Network(path).response(t1, Eigen::Vector3d(p_w, p_h, 0.0), 25.0, t_s);
  };
  const Eigen::Vector3d expected = response(share);
  EXPECT_NEAR(s2.winding_temp_C, expected(0), 0.01 * (expected(0) - 25.0));
  EXPECT_NEAR(s2.housing_temp_C, expected(1), 0.01 * (expected(1) - 25.0));
  EXPECT_GT(response(0.35)(1) - s2.housing_temp_C, 0.05 * (expected(1) - 25.0)) << "not the path at rest";
  EXPECT_GT(s2.housing_temp_C - response(1.0)(1), 0.05 * (expected(1) - 25.0)) << "nor the fan speed's";
}

TEST(plant_thermal, AShaftFansStepMustBeShortAgainstTheHousing) {
  // The fan's part enters each step explicitly: a step that is no small part of the housing's
  // time constant through its path at the largest share is refused, naming the keys.
  ThermalConfig t;
  t.fan_speed_rad_s = 314.0;
  const double tau_s = t.housing_capacity_J_K * t.housing_to_ambient_K_W /
                       ThermalNetwork::fan_share(t, ThermalNetwork::kFanSpeedSpan * t.fan_speed_rad_s);
  EXPECT_NO_THROW(ThermalNetwork(t, 0.9 * ThermalNetwork::kMaxFanStepFraction * tau_s));
  try {
    ThermalNetwork(t, 1.1 * ThermalNetwork::kMaxFanStepFraction * tau_s);
    ADD_FAILURE() << "a step past the bound was taken";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("thermal.fan_speed_rad_s: with a shaft fan a thermal step"), std::string::npos)
        << e.what();
  }
  ThermalConfig plain;  // no fan: any step is exact
  EXPECT_NO_THROW(ThermalNetwork(plain, 10.0 * tau_s));
  // Beyond twice its speed the share is held.
  EXPECT_DOUBLE_EQ(ThermalNetwork::fan_share(t, 5000.0), ThermalNetwork::fan_share(t, 628.0));
}

TEST(plant_thermal, AShaftFansShareGrowsWithTheSpeed) {
  ThermalConfig t;
  EXPECT_EQ(ThermalNetwork::fan_share(t, 500.0), 1.0);  // no fan: the path holds at every speed
  t.fan_speed_rad_s = 200.0;
  t.fan_standstill_share = 0.3;
  t.fan_exponent = 0.8;
  EXPECT_DOUBLE_EQ(ThermalNetwork::fan_share(t, 0.0), 0.3);
  EXPECT_DOUBLE_EQ(ThermalNetwork::fan_share(t, 200.0), 1.0);
  EXPECT_DOUBLE_EQ(ThermalNetwork::fan_share(t, -200.0), 1.0);  // either direction turns the fan
  EXPECT_NEAR(ThermalNetwork::fan_share(t, 20.0), 0.3 + 0.7 * std::pow(0.1, 0.8), 1e-12);
  EXPECT_GT(ThermalNetwork::fan_share(t, 400.0), 1.0);  // beyond its speed the fan moves more air
}

TEST(plant_thermal, ResistanceFollowsWindingTemperature) {
  // Eq. 1 with alpha = 3.93e-3: the current at constant voltage falls as the winding heats.
  const PlantConfig c = heating_config(3.93e-3);
  Plant plant(c);
  const double vd = 0.133 * 50.0;
  for (int i = 0; i < 20000; ++i) {
    plant.step_with_dq_voltage(vd, 0.0);
  }
  const PlantState s = plant.state();
  const double rs = 0.133 * (1.0 + 3.93e-3 * (s.winding_temp_C - 25.0));
  EXPECT_GT(s.winding_temp_C, 50.0);
  EXPECT_NEAR(s.rs_ohm, rs, 1e-6);
  EXPECT_NEAR(static_cast<double>(plant.truth().rs_ohm), rs, 1e-6);
  // Electrically: id = vd / Rs(T) (quasi-steady, the temperature moves slowly even when
  // accelerated 1000 times).
  EXPECT_NEAR(s.id_A, vd / rs, 0.005 * vd / rs);
}

TEST(plant_thermal, AmbientChangesAtRunTime) {
  PlantConfig c = heating_config(0.0);
  c.thermal.acceleration = 10000.0;
  Plant plant(c);
  plant.set_ambient_C(40.0);
  for (int i = 0; i < 20000; ++i) {  // 20000 s thermal, about 7 time constants
    plant.step_with_dq_voltage(0.0, 0.0);
  }
  EXPECT_NEAR(plant.state().winding_temp_C, 40.0, 0.05);
  EXPECT_NEAR(static_cast<double>(plant.truth().housing_temp_C), 40.0, 0.05);
}

}  // namespace
}  // namespace pmsm::plant
