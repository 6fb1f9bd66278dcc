// The plant in a closed current loop that sees only what a real drive sees: ADC codes, the
// encoder count and the DC-bus code, with the nominal calibration. The controller here is
// a minimal PI written for this test (the product's controller lives in core/ and is not
// used by the plant or its tests).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>

#include "pmsm/plant/plant.hpp"

namespace pmsm::plant {
namespace {

constexpr double kPi = std::numbers::pi;

class TestCurrentLoop {
 public:
  explicit TestCurrentLoop(const PlantConfig& c)
      : lsb_A_(c.current_adc.range_A / std::ldexp(1.0, c.current_adc.bits - 1)),
        lsb_V_(c.dc_bus_adc.full_scale_V / std::ldexp(1.0, c.dc_bus_adc.bits)),
        counts_(std::ldexp(1.0, c.encoder.bits)),
        ts_s_(1.0 / c.inverter.pwm_frequency_Hz) {}

  hal::InverterCommand step(const hal::SensorSample& s, double id_ref, double iq_ref) {
    const double theta_m = s.encoder_count / counts_ * 2.0 * kPi;
    const double theta_e = 3.0 * theta_m;
    if (have_prev_) {
      double d = theta_e - prev_theta_e_;
      d = std::remainder(d, 2.0 * kPi);
      omega_e_ += 0.05 * (d / ts_s_ - omega_e_);  // lightly filtered speed
    }
    prev_theta_e_ = theta_e;
    have_prev_ = true;
    const double ia = s.phase_current_adc[0] * lsb_A_;
    const double ib = s.phase_current_adc[1] * lsb_A_;
    const double ic = s.phase_current_adc[2] * lsb_A_;
    const double c0 = std::cos(theta_e);
    const double s0 = std::sin(theta_e);
    const double c1 = std::cos(theta_e - 2.0 * kPi / 3.0);
    const double s1 = std::sin(theta_e - 2.0 * kPi / 3.0);
    const double c2 = std::cos(theta_e + 2.0 * kPi / 3.0);
    const double s2 = std::sin(theta_e + 2.0 * kPi / 3.0);
    const double id = 2.0 / 3.0 * (ia * c0 + ib * c1 + ic * c2);
    const double iq = -2.0 / 3.0 * (ia * s0 + ib * s1 + ic * s2);
    // PI tuned for a 300 Hz bandwidth on L = 5.5 mH, R = 0.133 Ω.
    const double wc = 2.0 * kPi * 300.0;
    const double ed = id_ref - id;
    const double eq = iq_ref - iq;
    int_d_ += 0.133 * wc * ed * ts_s_;
    int_q_ += 0.133 * wc * eq * ts_s_;
    const double vd = 5.5e-3 * wc * ed + int_d_ - omega_e_ * 5.5e-3 * iq;
    const double vq = 5.5e-3 * wc * eq + int_q_ + omega_e_ * 5.5e-3 * id + omega_e_ * 0.324;
    const double vdc = std::max(s.dc_bus_adc * lsb_V_, 100.0);
    // The command acts one period later, on average 1.5 periods after this sample.
    const double th = theta_e + 1.5 * omega_e_ * ts_s_;
    std::array<double, 3> v{};
    for (std::size_t ph = 0; ph < 3; ++ph) {
      const double ang = th - 2.0 * kPi / 3.0 * static_cast<double>(ph);
      v[ph] = vd * std::cos(ang) - vq * std::sin(ang);
    }
    // Min-max zero sequence (equivalent to SVPWM) for the full linear range.
    const double offset = -0.5 * (*std::max_element(v.begin(), v.end()) +
                                  *std::min_element(v.begin(), v.end()));
    hal::InverterCommand cmd;
    cmd.sequence = s.sequence;
    cmd.enable = true;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      const double duty = std::clamp(0.5 + (v[ph] + offset) / vdc, 0.0, 1.0);
      cmd.duty[ph] = static_cast<std::uint16_t>(std::lround(duty * 65535.0));
    }
    return cmd;
  }

 private:
  double lsb_A_;
  double lsb_V_;
  double counts_;
  double ts_s_;
  double int_d_ = 0.0;
  double int_q_ = 0.0;
  double omega_e_ = 0.0;
  double prev_theta_e_ = 0.0;
  bool have_prev_ = false;
};

PlantConfig reference_at_speed(double speed_rad_s) {
  PlantConfig c = load_plant_config(std::filesystem::path(PMSM_SOURCE_DIR) / "plant-emulator" /
                                    "profiles" / "reference.toml");
  c.load.profile = LoadProfile::speed_cycle;
  c.load.speed_rad_s = speed_rad_s;
  return c;
}

TEST(plant_closed_loop, CurrentLoopOnReferenceProfile) {
  const PlantConfig c = reference_at_speed(150.0);
  Plant plant(c);
  TestCurrentLoop loop(c);
  const hal::SensorSample* s = &plant.sample();
  double iq_sum = 0.0;
  double id_sum = 0.0;
  double torque_sum = 0.0;
  int n = 0;
  for (int k = 0; k < 5000; ++k) {
    s = &plant.step(loop.step(*s, 0.0, 20.0));
    if (k >= 3000) {
      const PlantState st = plant.state();
      iq_sum += st.iq_A;
      id_sum += st.id_A;
      torque_sum += st.torque_em_Nm;
      ++n;
    }
  }
  // Gain errors of ±0.5 %, offsets and dead time bend the loop a little; the true current
  // still follows within a few percent.
  EXPECT_NEAR(iq_sum / n, 20.0, 0.4);
  EXPECT_NEAR(id_sum / n, 0.0, 0.4);
  const double psi = 1.19 * std::sqrt(2.0 / 3.0) / 3.0;
  EXPECT_NEAR(torque_sum / n, 1.5 * 3.0 * psi * 20.0, 0.03 * 1.5 * 3.0 * psi * 20.0);
  EXPECT_EQ(plant.command_sequence_errors(), 0U);
  EXPECT_FALSE(plant.sample().flags & hal::kSensorHardwareOvercurrent);
}

TEST(plant_closed_loop, AcceleratedHeatUpUnderLoad) {
  // 40 A of q current at 200 rad/s with the thermal network 500 times faster: 2 s of
  // simulation are 1000 s of heating. The winding must warm above the housing, the housing
  // above ambient, and the true resistance must follow Eq. 1.
  PlantConfig c = reference_at_speed(200.0);
  c.thermal.acceleration = 500.0;
  Plant plant(c);
  TestCurrentLoop loop(c);
  const hal::SensorSample* s = &plant.sample();
  for (int k = 0; k < 20000; ++k) {
    s = &plant.step(loop.step(*s, 0.0, 40.0));
  }
  const hal::TruthSample t = plant.truth();
  const double tw = static_cast<double>(t.winding_temp_C);
  const double th = static_cast<double>(t.housing_temp_C);
  EXPECT_GT(tw, th + 5.0);
  EXPECT_GT(th, 30.0);
  // Eq. 1 for copper: Rs proportional to 234.5 C + T.
  EXPECT_NEAR(static_cast<double>(t.rs_ohm), 0.133 * (234.5 + tw) / (234.5 + 25.0), 1e-5);
  EXPECT_GT(static_cast<double>(t.iron_loss_W), 10.0);
  EXPECT_GT(static_cast<double>(t.copper_loss_W), 300.0);
}

TEST(plant_closed_loop, LockstepRunsWellFasterThanRealTime) {
  const PlantConfig c = reference_at_speed(300.0);
  Plant plant(c);
  TestCurrentLoop loop(c);
  const hal::SensorSample* s = &plant.sample();
  constexpr int kPeriods = 20000;  // 2 s simulated
  const auto start = std::chrono::steady_clock::now();
  for (int k = 0; k < kPeriods; ++k) {
    s = &plant.step(loop.step(*s, -5.0, 15.0));
  }
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const double simulated_s = kPeriods * plant.period_s();
  RecordProperty("simulated_s_per_wall_s", std::to_string(simulated_s / wall_s));
  // A loose floor (sanitizer builds included); the benchmark in bench/ gives real figures.
  EXPECT_GT(simulated_s / wall_s, 2.0);
}

}  // namespace
}  // namespace pmsm::plant
