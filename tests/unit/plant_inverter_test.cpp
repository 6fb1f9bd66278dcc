// Inverter average model: dead time and device drop (including the linear region around
// zero current), freewheeling through the diodes with the gates off, uncontrolled
// rectification, and the hardware over-current trip.
#include <gtest/gtest.h>

#include <cmath>

#include "pmsm/plant/plant.hpp"

namespace pmsm::plant {
namespace {

// Ideal inverter and sensors, frozen temperature, shaft held by an ideal dynamometer.
PlantConfig bench_config(double speed_rad_s = 0.0) {
  PlantConfig c;
  c.emf.shape = EmfShape::sinusoidal;
  c.thermal.enabled = false;
  c.current_adc.noise_enabled = false;
  c.current_adc.offset_enabled = false;
  c.current_adc.gain_error_enabled = false;
  c.inverter.dc_ripple_enabled = false;
  c.inverter.dead_time_enabled = false;
  c.inverter.device_drop_enabled = false;
  c.load.profile = LoadProfile::speed_cycle;
  c.load.speed_rad_s = speed_rad_s;
  return c;
}

std::uint16_t duty_code(double duty) {
  return static_cast<std::uint16_t>(std::lround(duty * 65535.0));
}

// Duties a = 0.5 + delta, b = c = 0.5 - delta/2: at theta = 0 a pure d-axis voltage.
hal::InverterCommand d_axis_command(std::uint32_t seq, double delta) {
  hal::InverterCommand cmd;
  cmd.sequence = seq;
  cmd.enable = true;
  cmd.duty = {duty_code(0.5 + delta), duty_code(0.5 - 0.5 * delta), duty_code(0.5 - 0.5 * delta)};
  return cmd;
}

// Ideal phase-a voltage of a command: pole voltages minus their common mode.
double ideal_van(const hal::InverterCommand& cmd, double vdc) {
  const double a = cmd.duty[0] / 65535.0;
  const double b = cmd.duty[1] / 65535.0;
  const double c = cmd.duty[2] / 65535.0;
  return (a - (a + b + c) / 3.0) * vdc;
}

struct DeadTimeCase {
  double delta;
  bool linear_region;
};

class plant_inverter_dead_time : public ::testing::TestWithParam<DeadTimeCase> {};

TEST_P(plant_inverter_dead_time, VoltageErrorOpposesCurrent) {
  const DeadTimeCase param = GetParam();
  PlantConfig c = bench_config();
  c.inverter.dead_time_enabled = true;
  c.inverter.device_drop_enabled = true;
  Plant plant(c);
  for (std::uint32_t k = 0; k < 5000; ++k) {
    plant.step(d_axis_command(k, param.delta));
  }
  const PlantState s = plant.state();
  const double v_ideal = ideal_van(d_axis_command(0, param.delta), 650.0);
  // Pole-voltage error per phase: E = Td·fs·Vdc + Vf = 6.5 V + 1 V, opposing the current.
  const double e_V = 1.0e-6 * 10000.0 * 650.0 + 1.0;
  double expected_ia = 0.0;
  if (param.linear_region) {
    // All currents inside the ripple band: every pole error is -E·i/band; they sum to zero,
    // so the phase sees an extra resistance E/band.
    expected_ia = v_ideal / (0.133 + e_V / c.inverter.zero_current_band_A);
    EXPECT_LT(std::abs(s.phase_current_A[0]), c.inverter.zero_current_band_A);
  } else {
    // Signs (+, -, -): pole errors (-E, +E, +E), common mode E/3, so phase a loses 4E/3.
    expected_ia = (v_ideal - 4.0 * e_V / 3.0) / 0.133;
    EXPECT_NEAR(s.phase_voltage_avg_V[0], v_ideal - 4.0 * e_V / 3.0, 0.01);
  }
  EXPECT_NEAR(s.phase_current_A[0], expected_ia, 0.005 * std::abs(expected_ia));
  EXPECT_GT(s.phase_current_A[0], 0.0);
}

INSTANTIATE_TEST_SUITE_P(Regions, plant_inverter_dead_time,
                         ::testing::Values(DeadTimeCase{0.03, false}, DeadTimeCase{0.001, true}));

class plant_inverter_gates_off : public ::testing::TestWithParam<double> {};

TEST_P(plant_inverter_gates_off, CurrentsFreewheelToZeroAndStayThere) {
  const double speed = GetParam();
  PlantConfig c = bench_config(speed);
  c.inverter.device_drop_enabled = true;
  Plant plant(c);
  // Establish a current, then turn the gates off.
  std::uint32_t k = 0;
  for (; k < 3000; ++k) {
    hal::InverterCommand cmd;
    if (speed == 0.0) {
      cmd = d_axis_command(k, 0.01);
    } else {
      // At speed: hold the duties at 50 % so the EMF drives the current.
      cmd.sequence = k;
      cmd.enable = true;
      cmd.duty = {32768, 32768, 32768};
    }
    plant.step(cmd);
  }
  const PlantState before = plant.state();
  const double i0 = std::max({std::abs(before.phase_current_A[0]),
                              std::abs(before.phase_current_A[1]),
                              std::abs(before.phase_current_A[2])});
  ASSERT_GT(i0, 10.0);
  int nonzero_periods = 0;
  for (int n = 0; n < 400; ++n, ++k) {
    hal::InverterCommand off;
    off.sequence = k;
    plant.step(off);
    const PlantState s = plant.state();
    const bool zero =
        s.phase_current_A[0] == 0.0 && s.phase_current_A[1] == 0.0 && s.phase_current_A[2] == 0.0;
    if (!zero) {
      ASSERT_EQ(nonzero_periods, n) << "current reappeared after reaching zero";
      ++nonzero_periods;
    }
  }
  // Period k of the off command is still driven (one-period delay); the diodes then put
  // about -2/3·(Vdc + Vf) across the phase, so 50 A is gone in well under ten periods.
  EXPECT_LE(nonzero_periods, 12);
  if (speed == 0.0) {
    // Standstill, phase a positive and b, c negative and equal: all reach zero together at
    // t = L/R·ln(1 + i0·R/V), V = 2/3·(Vdc + Vf), counted from the start of the off period.
    const double v = 2.0 / 3.0 * (650.0 + 1.0);
    const double t_zero = 5.5e-3 / 0.133 * std::log(1.0 + before.phase_current_A[0] * 0.133 / v);
    const int expected = 1 + static_cast<int>(std::ceil(t_zero / 1e-4));
    EXPECT_NEAR(nonzero_periods, expected, 1);
  }
}

INSTANTIATE_TEST_SUITE_P(Speeds, plant_inverter_gates_off, ::testing::Values(0.0, 100.0));

TEST(plant_inverter, NoConductionBelowTheBusRectificationAbove) {
  // Line EMF peak sqrt(3)·psi_m·p·ω_m exceeds Vdc + 2·Vf = 652 V above about 387 rad/s.
  auto run = [](double speed, double& max_current, double& mean_torque) {
    PlantConfig c = bench_config(speed);
    c.inverter.device_drop_enabled = true;
    Plant plant(c);
    max_current = 0.0;
    mean_torque = 0.0;
    for (std::uint32_t k = 0; k < 1000; ++k) {
      hal::InverterCommand off;
      off.sequence = k;
      plant.step(off);
      const PlantState s = plant.state();
      for (double i : s.phase_current_A) {
        max_current = std::max(max_current, std::abs(i));
      }
      mean_torque += s.torque_em_Nm / 1000.0;
    }
  };
  double i_max = 0.0;
  double torque = 0.0;
  run(350.0, i_max, torque);
  EXPECT_EQ(i_max, 0.0);
  EXPECT_EQ(torque, 0.0);
  run(450.0, i_max, torque);
  EXPECT_GT(i_max, 5.0);
  EXPECT_LT(torque, -0.5);  // the rectifier brakes the shaft
}

TEST(plant_inverter, HardwareOvercurrentTripsAndClears) {
  PlantConfig c = bench_config();
  Plant plant(c);
  std::uint32_t k = 0;
  bool tripped = false;
  for (; k < 400 && !tripped; ++k) {
    tripped = plant.step(d_axis_command(k, 0.2)).flags & hal::kSensorHardwareOvercurrent;
  }
  ASSERT_TRUE(tripped);
  EXPECT_FALSE(plant.sample().flags & hal::kSensorOutputEnabled);
  EXPECT_GT(plant.state().phase_current_A[0], c.inverter.overcurrent_trip_A);
  // The controller keeps asking for current: the latch holds the gates off regardless.
  for (int n = 0; n < 50; ++n, ++k) {
    const hal::SensorSample& s = plant.step(d_axis_command(k, 0.2));
    EXPECT_TRUE(s.flags & hal::kSensorHardwareOvercurrent);
  }
  EXPECT_EQ(plant.state().phase_current_A[0], 0.0);
  // A disabling command acknowledges the trip.
  hal::InverterCommand off;
  off.sequence = k++;
  const hal::SensorSample& s = plant.step(off);
  EXPECT_FALSE(s.flags & hal::kSensorHardwareOvercurrent);
  plant.step(d_axis_command(k++, 0.01));
  plant.step(d_axis_command(k++, 0.01));
  EXPECT_GT(plant.state().phase_current_A[0], 0.1);  // switching again
}

// The supply's voltage over time (inverter.dc_source_points): the bus follows it between
// periods, linearly between the table's points and in one period at a repeated time.
TEST(plant_inverter, TheBusFollowsTheSupplysTable) {
  PlantConfig c = bench_config();
  c.inverter.dc_source_points = {{0.0, 600.0}, {0.01, 700.0}, {0.02, 700.0}, {0.02, 500.0}};
  c.dc_bus_adc.noise_enabled = false;
  Plant plant(c);
  hal::InverterCommand off;
  auto run_to = [&](std::uint32_t period) {
    while (plant.period() < period) {
      off.sequence = plant.period();
      plant.step(off);
    }
  };
  EXPECT_DOUBLE_EQ(plant.state().dc_bus_V, 600.0);
  run_to(50);  // t = 5 ms: halfway up the ramp
  EXPECT_NEAR(plant.state().dc_bus_V, 650.0, 1e-9);
  run_to(199);
  EXPECT_NEAR(plant.state().dc_bus_V, 700.0, 1e-9);
  run_to(201);  // past the step at 20 ms
  EXPECT_DOUBLE_EQ(plant.state().dc_bus_V, 500.0);
  // The drive's bus sensor reads it (12-bit ADC, its full scale over 4096 codes).
  EXPECT_NEAR(plant.sample().dc_bus_adc * c.dc_bus_adc.full_scale_V / 4096.0, 500.0, c.dc_bus_adc.full_scale_V / 4096.0);
}

// A supply with a resistance behind the DC link sags by R times the current the bridge draws.
// A d-axis voltage d Vdc at standstill drives id = d Vdc / Rs, and the motor takes
// P = 3/2 (d Vdc)^2 / Rs, so the settled bus solves Vdc = Vs - R P / Vdc:
// Vdc = Vs / (1 + 3/2 R d^2 / Rs).
TEST(plant_inverter, ASupplysResistanceSagsTheBusByTheCurrentDrawn) {
  PlantConfig c = bench_config();
  c.inverter.dc_source_resistance_ohm = 20.0;
  c.inverter.dc_link_capacitance_F = 1.0e-3;  // 20 ms
  constexpr double kDelta = 0.01;
  Plant plant(c);
  for (std::uint32_t k = 0; k < 5000; ++k) {  // 0.5 s: ten of the winding's L / R, 25 of R C
    plant.step(d_axis_command(plant.period(), kDelta));
  }
  const PlantState s = plant.state();
  const double expected = c.inverter.dc_bus_V / (1.0 + 1.5 * c.inverter.dc_source_resistance_ohm * kDelta * kDelta / s.rs_ohm);
  ASSERT_GT(s.id_A, 40.0) << "the command no longer drives a current";
  EXPECT_NEAR(s.dc_bus_V, expected, 0.002 * (c.inverter.dc_bus_V - expected));
  // Gates off: nothing drawn, the bus recovers to the supply's voltage.
  hal::InverterCommand off;
  for (int n = 0; n < 3000; ++n) {
    off.sequence = plant.period();
    plant.step(off);
  }
  EXPECT_NEAR(plant.state().dc_bus_V, c.inverter.dc_bus_V, 1e-6 * c.inverter.dc_bus_V);
}

}  // namespace
}  // namespace pmsm::plant
