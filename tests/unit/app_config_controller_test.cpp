// The controller's configuration: defaults (Table I and the documented settings), the fields
// finalize() derives, the cross-key rules, and errors that name file, line and key.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <string_view>
#include <vector>

#include <toml++/toml.h>

#include "config_schema.hpp"
#include "controller_config.hpp"
#include "pmsm/core/injection.hpp"
#include "pmsm/core/speed_controller.hpp"
#include "pmsm/core/window.hpp"

namespace pmsm::app {
namespace {

ControllerConfig parse(std::string_view text) {
  return parse_controller_config(toml::parse(text, std::string_view{"drive.toml"}), "drive.toml", {});
}

std::string error_of(std::string_view text) {
  try {
    (void)parse(text);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

// sqrt(2/3): line-to-line RMS to phase peak.
const double kLlRmsToPeak = std::sqrt(2.0 / 3.0);

TEST(ControllerConfig, DefaultsAreTableIAndTheDocumentedSettings) {
  const ControllerConfig c = default_controller_config();
  const core::DriveConfig& d = c.drive;
  // Table I.
  EXPECT_EQ(d.motor.rs_ohm, 0.133);
  EXPECT_EQ(d.motor.rs_reference_temp_C, 25.0);
  EXPECT_EQ(d.motor.ke_V_s_per_rad, 1.19);
  EXPECT_EQ(d.motor.pole_pairs, 3);
  EXPECT_EQ(d.motor.inertia_kg_m2, 0.00841);
  EXPECT_EQ(d.motor.ld_H, 5.5e-3);  // half of the 11 mH line-to-line inductance
  EXPECT_EQ(d.motor.lq_H, 5.5e-3);
  // The method's, the thermal model's and the derating's settings are the core structs'
  // documented defaults (injection_scheduler.hpp, thermal_observer.hpp): the configuration
  // must not change them behind the reader's back.
  const core::InjectionConfig inj;
  EXPECT_EQ(d.injection.method, inj.method);
  EXPECT_EQ(d.injection.separation, inj.separation);
  EXPECT_EQ(d.injection.f_A, inj.f_A);
  EXPECT_EQ(d.injection.f_min_A, inj.f_min_A);
  EXPECT_EQ(d.injection.level_count, inj.level_count);
  EXPECT_EQ(d.injection.levels, inj.levels);
  EXPECT_EQ(d.injection.tw_s, inj.tw_s);
  EXPECT_EQ(d.injection.settle_s, inj.settle_s);
  EXPECT_EQ(d.injection.rs_min_ohm, inj.rs_min_ohm);
  EXPECT_EQ(d.injection.rs_max_ohm, inj.rs_max_ohm);
  EXPECT_EQ(d.injection.mechanical_harmonics, inj.mechanical_harmonics);
  EXPECT_EQ(d.injection.max_residual_V, inj.max_residual_V);
  const core::DeratingConfig der;
  EXPECT_EQ(d.derating.max_current_A, der.max_current_A);
  EXPECT_EQ(d.derating.min_current_A, der.min_current_A);
  EXPECT_EQ(d.derating.derate_start_C, der.derate_start_C);
  EXPECT_EQ(d.derating.limit_C, der.limit_C);
  EXPECT_EQ(d.derating.confidence_sigma, der.confidence_sigma);
  const core::ThermalModelConfig th;
  EXPECT_EQ(d.thermal.winding_capacity_J_K, th.winding_capacity_J_K);
  EXPECT_EQ(d.thermal.gate_sigma, th.gate_sigma);
  EXPECT_EQ(d.thermal.huber_sigma, th.huber_sigma);
  EXPECT_EQ(d.thermal.time_scale, 1.0);  // a real machine
  // As DESIGN section 4 and the headers state them.
  EXPECT_EQ(d.injection.rs_min_ohm, 0.09);
  EXPECT_EQ(d.injection.rs_max_ohm, 0.27);
  EXPECT_EQ(d.derating.limit_C, 155.0);
  EXPECT_EQ(c.nominal_dc_bus_V, 650.0);
}

TEST(ControllerConfig, FinalizeDerivesTheDependentFields) {
  const ControllerConfig c = default_controller_config();
  const core::DriveConfig& d = c.drive;
  const double psi = 1.19 * kLlRmsToPeak / 3.0;  // 0.3239 Wb
  EXPECT_NEAR(d.injection.flux_linkage_Wb, psi, 1e-12);
  EXPECT_NEAR(d.current.flux_linkage_Wb, psi, 1e-12);
  EXPECT_NEAR(d.baseline.initial_ke_V_s_per_rad, 1.19 * kLlRmsToPeak, 1e-12);
  EXPECT_EQ(d.injection.ld_H, d.motor.ld_H);
  EXPECT_EQ(d.injection.lq_H, d.motor.lq_H);
  EXPECT_EQ(d.injection.rs_nominal_ohm, d.motor.rs_ohm);
  EXPECT_EQ(d.injection.pole_pairs, 3);
  EXPECT_EQ(d.angle.pole_pairs, 3);
  EXPECT_EQ(d.angle.period_s, d.period_s);
  EXPECT_NEAR(d.speed.period_s, 10.0 * d.period_s, 1e-15);
  EXPECT_EQ(d.current.rs_ohm, 0.133);
  // The injection shares the derating's current budget.
  EXPECT_EQ(d.injection.current_limit_A, d.derating.max_current_A);
  // The inverter-error prior: what the compensation assumes at the nominal bus,
  // 0.9 us / 100 us * 650 V + 0 V = 5.85 V.
  EXPECT_NEAR(d.injection.vx_initial_V, 5.85, 1e-12);
  // Calibration runs fixed-magnitude bipolar at two levels whatever the run-time method.
  EXPECT_EQ(d.calibration_injection.method, core::InjectionMethod::kFixedMagnitude);
  EXPECT_EQ(d.calibration_injection.separation, core::Separation::kBipolar);
  EXPECT_EQ(d.calibration_injection.level_count, 2);
  EXPECT_EQ(d.calibration_injection.levels[1], 0.4);
  // Rs0 never comes from field-weakening pairs (their bias would stay in every estimate).
  EXPECT_TRUE(d.injection.field_weakening_pairs);
  EXPECT_FALSE(d.calibration_injection.field_weakening_pairs);
}

// `> 0` let a denormal through: motor.ld_H = 5e-324 passed the check, and the drive's first
// step divided it into a non-finite voltage (INTERNAL). Every physical quantity has a floor far
// below any machine; the file is refused, naming the key.
TEST(ControllerConfig, ANumberTooSmallForAnyMachineIsRefused) {
  for (const char* key : {"motor.rs_ohm", "motor.ld_H", "motor.lq_H", "motor.ke_V_s_per_rad", "motor.continuous_current_A_rms",
                          "motor.rated_speed_rad_s", "motor.inertia_kg_m2", "thermal.winding_capacity_J_K",
                          "thermal.housing_capacity_J_K", "thermal.winding_to_housing_K_W", "thermal.housing_to_ambient_K_W",
                          "calibration.rs0_ohm"}) {
    const std::string k(key);
    const std::string section = k.substr(0, k.find('.'));
    const std::string text = "[" + section + "]\n" + k.substr(k.find('.') + 1) + " = 5e-324\n";
    EXPECT_NE(error_of(text).find(k + ": must be in ["), std::string::npos) << key << ": " << error_of(text);
  }
}

TEST(ControllerConfig, AnEmptyFileGivesTheDefaults) {
  const ControllerConfig parsed = parse("");
  const ControllerConfig defaults = default_controller_config();
  EXPECT_EQ(controller_schema().markdown(parsed), controller_schema().markdown(defaults));
  EXPECT_EQ(parsed.drive.calibration.rs0_ohm, 0.133);
  EXPECT_EQ(parsed.drive.calibration.t0_C, 25.0);
  EXPECT_NEAR(parsed.drive.injection.vx_initial_V, 5.85, 1e-12);
}

TEST(ControllerConfig, DerivedFieldsFollowTheFile) {
  const ControllerConfig c = parse(R"(
[motor]
rs_ohm = 0.2
rs_reference_temp_C = 20.0
ke_V_s_per_rad = 1.3
pole_pairs = 4
ld_H = 7e-3
[control]
period_s = 5e-5
speed_decimation = 20
nominal_dc_bus_V = 600
dead_time_s = 1.5e-6
device_drop_V = 1.2
[injection]
method = "dc"
levels = [1.0, 0.6, 0.3]
[derating]
max_current_A = 60
)");
  const core::DriveConfig& d = c.drive;
  const double psi = 1.3 * kLlRmsToPeak / 4.0;
  EXPECT_NEAR(d.injection.flux_linkage_Wb, psi, 1e-12);
  EXPECT_NEAR(d.current.flux_linkage_Wb, psi, 1e-12);
  EXPECT_EQ(d.injection.pole_pairs, 4);
  EXPECT_EQ(d.angle.pole_pairs, 4);
  EXPECT_EQ(d.injection.ld_H, 7e-3);
  EXPECT_EQ(d.current.ld_H, 7e-3);
  EXPECT_EQ(d.baseline.ld_H, 7e-3);
  EXPECT_NEAR(d.speed.period_s, 1e-3, 1e-15);
  EXPECT_EQ(d.baseline.period_s, 5e-5);
  EXPECT_EQ(d.injection.current_limit_A, 60.0);
  EXPECT_EQ(d.calibration_injection.current_limit_A, 60.0);
  // 1.5 us / 50 us * 600 V + 1.2 V
  EXPECT_NEAR(d.injection.vx_initial_V, 1.5e-6 / 5e-5 * 600.0 + 1.2, 1e-12);
  // The stored calibration defaults to the nameplate.
  EXPECT_EQ(d.calibration.rs0_ohm, 0.2);
  EXPECT_EQ(d.calibration.t0_C, 20.0);
  // Levels beyond the list are cleared.
  EXPECT_EQ(d.injection.level_count, 3);
  EXPECT_EQ(d.injection.levels[3], 0.0);
  EXPECT_EQ(d.injection.method, core::InjectionMethod::kDc);
  EXPECT_EQ(d.calibration_injection.method, core::InjectionMethod::kFixedMagnitude);
  EXPECT_EQ(d.calibration_injection.level_count, 2);
}

TEST(ControllerConfig, GivenValuesAreNotOverwritten) {
  const ControllerConfig c = parse(R"(
[injection]
vx_initial_V = 2.5
[calibration]
rs0_ohm = 0.14
t0_C = 22.0
)");
  EXPECT_EQ(c.drive.injection.vx_initial_V, 2.5);
  EXPECT_FALSE(c.vx_initial_from_compensation);
  EXPECT_EQ(c.drive.calibration.rs0_ohm, 0.14);
  EXPECT_EQ(c.drive.calibration.t0_C, 22.0);
}

TEST(ControllerConfig, ErrorsNameFileLineAndKey) {
  EXPECT_EQ(error_of("[injection]\nF_A = 2000\n"), "drive.toml:2: injection.F_A: must be in (0, 1000], got 2000");
  // SENSOR_SAMPLE's EncoderCount is 16 bits: a wider encoder made every count look plausible.
  EXPECT_EQ(error_of("[sensors]\nencoder_bits = 24\n"), "drive.toml:2: sensors.encoder_bits: must be in [8, 16], got 24");
  EXPECT_EQ(error_of("[injection]\nF_AA = 20\n"), "drive.toml:2: injection.F_AA: unknown key (did you mean injection.F_A?)");
  // A key without its unit: the key that is it plus its unit (rs_ohm, not rs_reference_temp_C;
  // J/K spelled J_K), and no guess where no key is (winding: no unit makes a key of it).
  EXPECT_EQ(error_of("[motor]\nrs = 0.9\n"), "drive.toml:2: motor.rs: unknown key (did you mean motor.rs_ohm?)");
  EXPECT_EQ(error_of("[thermal]\nwinding_capacity = 300\n"),
            "drive.toml:2: thermal.winding_capacity: unknown key (did you mean thermal.winding_capacity_J_K?)");
  EXPECT_EQ(error_of("[thermal]\nwinding = 300\n"), "drive.toml:2: thermal.winding: unknown key");
  EXPECT_EQ(error_of("[motor]\n\npole_pairs = 3.0\n"), "drive.toml:3: motor.pole_pairs: expected an integer, got a number");
  EXPECT_EQ(error_of("[injection]\nlevels = [1.0, 0.8, 0.6, 0.4, 0.2]\n"),
            "drive.toml:2: injection.levels: expected 1 to 4 values, got 5");
  EXPECT_EQ(error_of("[injection]\nmethod = \"sinusoidal\"\n"),
            "drive.toml:2: injection.method: expected one of \"fixed-magnitude\", \"fixed-angle\", \"dc\", \"none\", got \"sinusoidal\"");
  EXPECT_EQ(error_of("[injection]\nfit_dead_time = \"yes\"\n"),
            "drive.toml:2: injection.fit_dead_time: expected true or false, got a string");
  EXPECT_EQ(error_of("[thermal]\ngate_sigma = 0\n"), "drive.toml:2: thermal.gate_sigma: must be in (0, 1000], got 0");
  // Huber's weight below 1 sigma would weigh down measurements that agree with the prediction.
  EXPECT_EQ(error_of("[thermal]\nhuber_sigma = 0.5\n"), "drive.toml:2: thermal.huber_sigma: must be in [1, 1000], got 0.5");
  EXPECT_EQ(error_of("[thermal]\nhuber_sigma = 1001\n"), "drive.toml:2: thermal.huber_sigma: must be in [1, 1000], got 1001");
  // A pair whose budget leaves no current would run without injection: F_min_A is no zero.
  EXPECT_EQ(error_of("[injection]\nF_min_A = 0\n"), "drive.toml:2: injection.F_min_A: must be in (0, 1000], got 0");
  EXPECT_EQ(error_of("[motr]\nrs_ohm = 0.1\n"), "drive.toml:1: motr: unknown key (did you mean [motor]?)");
}

TEST(ControllerConfig, CrossKeyRulesNameBothKeys) {
  EXPECT_EQ(error_of("[injection]\nrs_min_ohm = 0.3\nrs_max_ohm = 0.2\n"),
            "drive.toml:2: injection.rs_min_ohm (0.3 ohm) must be below injection.rs_max_ohm (0.2 ohm, drive.toml:3)");
  EXPECT_EQ(error_of("[derating]\nstart_C = 160\nlimit_C = 155\n"), "drive.toml:2: derating.start_C (160 C) must be below derating.limit_C (155 C, drive.toml:3)");
  EXPECT_EQ(error_of("[derating]\nmin_current_A = 90\n"),
            "drive.toml:2: derating.min_current_A (90 A) must not exceed derating.max_current_A (80 A, its default)");
  EXPECT_EQ(error_of("[derating]\nmax_current_A = 250\n"),
            "drive.toml:2: derating.max_current_A (250 A) must be below sensors.current_range_A (200 A, its default)");
  EXPECT_EQ(error_of("[injection]\nF_A = 4\n"),
            "drive.toml:2: injection.F_min_A (5 A, its default) must not exceed injection.F_A (4 A) times the smallest "
            "of injection.levels (0.4)");
  EXPECT_EQ(error_of("[injection]\nsettle_s = 0.05\n"),
            "drive.toml:2: injection.record_time_s (0.05 s, its default) must be longer than injection.settle_s (0.05 s) "
            "by two control periods");
  EXPECT_EQ(error_of("[injection]\nfield_weakening_record_min_time_s = 10\nmin_speed_for_angle_rad_s = 2\n"),
            "drive.toml:2: recordings of up to 13.14 s (the longest of injection.record_time_s, record_min_time_s and "
            "field_weakening_record_min_time_s, plus one turn at injection.min_speed_for_angle_rad_s = 2 rad/s) do not "
            "fit the 13.11 s the recorder can hold at control.period_s = 0.0001 s (at most 131072 samples)");
  // A tiny speed is a number of a few digits, not of three hundred ({:.3f} printed them all).
  EXPECT_NE(error_of("[injection]\nmin_speed_for_angle_rad_s = 1e-300\n").find("recordings of up to 6.283e+300 s"), std::string::npos);
  // Equal ends are rejected too (the derating would divide by zero).
  EXPECT_NE(error_of("[derating]\nstart_C = 155\nlimit_C = 155\n"), "");
  EXPECT_EQ(error_of("[derating]\nmagnet_start_C = 150\n"),
            "drive.toml:2: derating.magnet_start_C (150 C) must be below derating.magnet_limit_C (150 C, its default)");
  EXPECT_NE(error_of("[derating]\nmagnet_start_C = 90\nmagnet_limit_C = 90\n"), "");
  // The thermal filter's step against its model's fastest time constant (132 s with the
  // defaults): 40000 x 10 ms is 400 s a step, where the prediction diverged to -1e96 C.
  EXPECT_EQ(error_of("[thermal]\nacceleration = 40000\n"),
            "drive.toml:2: thermal.update_s (0.01 s, its default) times thermal.acceleration (40000) is 400 s of thermal "
            "time per update, more than 0.5 of the thermal model's fastest time constant, 132.159 s "
            "(thermal.winding_capacity_J_K with its resistances): the filter's prediction would be wrong, and beyond "
            "twice it diverge; shorten thermal.update_s or lower the acceleration");
  EXPECT_EQ(error_of("[thermal]\nacceleration = 6000\n"), "") << "60 s a step";
}

// motor.rs_ohm outside the resistance plausibility window: no estimate near the reference
// temperature would ever be accepted (the Table I window on a 1.6 ohm servo).
TEST(ControllerConfig, NameplateResistanceOutsideTheWindowIsAnError) {
  EXPECT_EQ(error_of("[motor]\nrs_ohm = 1.6\n[injection]\nrs_max_ohm = 0.27\n"),
            "drive.toml:4: motor.rs_ohm (1.6 ohm, drive.toml:2) lies above injection.rs_max_ohm (0.27 ohm): the plausibility "
            "window would reject every resistance estimate near the reference temperature");
  EXPECT_EQ(error_of("[injection]\nrs_min_ohm = 0.15\n"),
            "drive.toml:2: motor.rs_ohm (0.133 ohm, its default) lies below injection.rs_min_ohm (0.15 ohm): the plausibility "
            "window would reject every resistance estimate near the reference temperature");
  // Inside the window it is fine, and a window relative to the motor always holds it.
  EXPECT_EQ(error_of("[motor]\nrs_ohm = 0.2\n[injection]\nrs_max_ohm = 0.27\n"), "");
  EXPECT_EQ(error_of("[motor]\nrs_ohm = 5.0\n"), "");
}

// A stored calibration's Rs0 outside the window contradicts it the same way.
TEST(ControllerConfig, CalibrationResistanceOutsideTheWindowIsAnError) {
  EXPECT_EQ(error_of("[calibration]\nrs0_ohm = 0.05\n"),
            "drive.toml:2: calibration.rs0_ohm (0.05 ohm) lies below injection.rs_min_ohm (0.09 ohm, its default): the "
            "plausibility window would reject every resistance estimate near the reference temperature");
  EXPECT_EQ(error_of("[injection]\nrs_max_ohm = 0.2\n[calibration]\nrs0_ohm = 0.25\n"),
            "drive.toml:2: calibration.rs0_ohm (0.25 ohm, drive.toml:4) lies above injection.rs_max_ohm (0.2 ohm): the "
            "plausibility window would reject every resistance estimate near the reference temperature");
}

// A motor cable adds to the nameplate's winding where the drive needs what it measures: an
// uncalibrated Rs0 and the plausibility window (the winding's temperatures plus the cable). A
// stored Rs0 the cable takes whole is an error; a negative cable is out of range.
TEST(ControllerConfig, AMotorCableAddsToTheNameplateWhereTheDriveMeasures) {
  const ControllerConfig c = parse("[motor]\nrs_ohm = 0.33\ncable_resistance_ohm = 0.0717\n");
  const double cable_25 = 0.0717 * (234.5 + 25.0) / (234.5 + 20.0);
  EXPECT_EQ(c.drive.thermal.cable_resistance_20C_ohm, 0.0717);
  EXPECT_DOUBLE_EQ(c.drive.calibration.rs0_ohm, 0.33 + cable_25);
  EXPECT_DOUBLE_EQ(c.drive.injection.rs_min_ohm, 0.09 / 0.133 * 0.33 + cable_25);
  EXPECT_DOUBLE_EQ(c.drive.injection.rs_max_ohm, 0.27 / 0.133 * 0.33 + cable_25);
  EXPECT_DOUBLE_EQ(core::with_motor_derived(c.drive).current.rs_ohm, 0.33 + cable_25);
  EXPECT_EQ(error_of("[motor]\ncable_resistance_ohm = 0.14\n"), "") << "any cable beside a nameplate winding";
  EXPECT_EQ(error_of("[motor]\ncable_resistance_ohm = 0.12\n[calibration]\nrs0_ohm = 0.1\nt0_C = 20\n[injection]\n"
                     "rs_min_ohm = 0.05\n"),
            "drive.toml:2: motor.cable_resistance_ohm (0.12 ohm) is 0.12 ohm at 20 C, not below the "
            "calibration's Rs0 (0.1 ohm), the whole resistance the drive measures: it would leave no winding for Eq. 1");
  EXPECT_EQ(error_of("[motor]\ncable_resistance_ohm = 0.03\n[calibration]\nrs0_ohm = 0.15\nt0_C = 20\n"), "");
  EXPECT_NE(error_of("[motor]\ncable_resistance_ohm = -0.01\n").find("motor.cable_resistance_ohm"), std::string::npos);
}

// The defaults that scale with the motor give exactly the Table I numbers at Table I.
TEST(ControllerConfig, MotorRelativeDefaultsAreTableIAtTableI) {
  const ControllerConfig c = default_controller_config();
  const core::DriveConfig& d = c.drive;
  EXPECT_EQ(d.injection.rs_min_ohm, 0.09);
  EXPECT_EQ(d.injection.rs_max_ohm, 0.27);
  EXPECT_EQ(d.injection.max_load_change_A, 1.5);
  EXPECT_EQ(d.injection.max_speed_change_rad_s, 3.0);
  EXPECT_EQ(d.injection.f_A, 35.0);
  EXPECT_EQ(d.injection.f_min_A, 5.0);
  EXPECT_EQ(c.calibration_f_A, 50.0);
  EXPECT_EQ(d.calibration_injection.f_A, 50.0);
  EXPECT_EQ(d.injection.headroom_margin_V, 15.0);  // at the Table I drive's 650 V bus
  EXPECT_EQ(d.thermal.initial_loss_error_std_W, 50.0);  // at the Table I model's 0.125 K/W to ambient
  EXPECT_EQ(d.thermal.loss_error_process_std_W_per_sqrt_s, 0.5);
  EXPECT_EQ(d.injection.tw_s, 0.004);  // the paper's: the calibration's edge asks 37 % of the limit
  EXPECT_EQ(d.calibration_injection.tw_s, 0.004);
  // Given keys win over the rule.
  const ControllerConfig g = parse("[injection]\nF_A = 20\nrs_max_ohm = 0.3\n[calibration]\nF_A = 30\n");
  EXPECT_EQ(g.drive.injection.f_A, 20.0);
  EXPECT_EQ(g.drive.injection.rs_max_ohm, 0.3);
  EXPECT_EQ(g.calibration_f_A, 30.0);
  EXPECT_EQ(g.drive.calibration_injection.f_A, 30.0);
}

// Vx's drift between events: a share of the Vx held by default (the reference's 5 mV at its
// 7.5 V bridge), no absolute part; both keys given win, the calibration's events drift alike,
// and values out of range name the key.
TEST(ControllerConfig, VxDriftsByAShareOfItselfByDefault) {
  const ControllerConfig d = default_controller_config();
  EXPECT_EQ(d.drive.injection.vx_drift_fraction, core::kReferenceVxDriftFraction);
  EXPECT_EQ(d.drive.injection.vx_drift_std_V, 0.0);
  EXPECT_EQ(d.drive.calibration_injection.vx_drift_fraction, core::kReferenceVxDriftFraction);
  const ControllerConfig g = parse("[injection]\nvx_drift_fraction = 0.002\nvx_drift_std_V = 0.001\n");
  EXPECT_EQ(g.drive.injection.vx_drift_fraction, 0.002);
  EXPECT_EQ(g.drive.injection.vx_drift_std_V, 0.001);
  EXPECT_EQ(g.drive.calibration_injection.vx_drift_fraction, 0.002);
  EXPECT_EQ(g.drive.calibration_injection.vx_drift_std_V, 0.001);
  EXPECT_EQ(error_of("[injection]\nvx_drift_fraction = 1.5\n"),
            "drive.toml:2: injection.vx_drift_fraction: must be in [0, 1], got 1.5");
  EXPECT_EQ(error_of("[injection]\nvx_drift_fraction = -0.1\n"),
            "drive.toml:2: injection.vx_drift_fraction: must be in [0, 1], got -0.1");
  EXPECT_NE(error_of("[injection]\nvx_drift_fraction = nan\n").find("injection.vx_drift_fraction"), std::string::npos);
}

// The pair recorder holds the longest recording the keys ask for: 8192 samples at least, more on a
// fast drive. A 32 kHz drive with every injection key at its default (0.12 s field-weakening
// recordings and a turn at 30 rad/s, 0.33 s: 10,544 samples) was refused, its 8192 holding 0.256 s.
TEST(ControllerConfig, TheRecorderHoldsTheLongestRecordingAtAnyControlRate) {
  EXPECT_EQ(default_controller_config().drive.recording_capacity, 8192U);
  const ControllerConfig fast = parse("[control]\nperiod_s = 3.125e-5\n");
  EXPECT_EQ(fast.drive.recording_capacity, 10544U);
  EXPECT_EQ(parse("[injection]\nfield_weakening_record_min_time_s = 0.7\n").drive.recording_capacity, 9096U);
}

// Vx is learned up to 600 electrical rad/s, and faster where the control periods are short
// enough that the rotor turns at most 0.06 rad in one: a 16 kHz drive up to 960 rad/s, a 20 kHz
// one up to 1200; a 4 kHz drive keeps 600 (0.15 rad a period, where a blower's calibration
// learned it right). The calibration's procedure takes the same; a given key holds as given.
TEST(ControllerConfig, TheVxLearningSpeedFollowsTheControlRateAbove10kHz) {
  EXPECT_EQ(default_controller_config().drive.injection.vx_learning_max_speed_rad_s, 600.0);
  const ControllerConfig slow = parse("[control]\nperiod_s = 2.5e-4\n");
  EXPECT_EQ(slow.drive.injection.vx_learning_max_speed_rad_s, 600.0);
  const ControllerConfig fast = parse("[control]\nperiod_s = 6.25e-5\n");
  EXPECT_DOUBLE_EQ(fast.drive.injection.vx_learning_max_speed_rad_s, 960.0);
  EXPECT_DOUBLE_EQ(fast.drive.calibration_injection.vx_learning_max_speed_rad_s, 960.0);
  EXPECT_DOUBLE_EQ(parse("[control]\nperiod_s = 5e-5\n").drive.injection.vx_learning_max_speed_rad_s, 1200.0);
  const ControllerConfig given = parse("[control]\nperiod_s = 6.25e-5\n[injection]\nvx_learning_max_speed_rad_s = 500\n");
  EXPECT_EQ(given.drive.injection.vx_learning_max_speed_rad_s, 500.0);
  EXPECT_NE(error_of("[injection]\nvx_learning_max_speed_rad_s = -1\n").find("injection.vx_learning_max_speed_rad_s"),
            std::string::npos);
}

// The window's period follows the edge's inductive voltage, k Ld F / Tw (Eq. 29): where the
// paper's 4 ms would take more than half the phase voltage limit it is lengthened to take half.
// A 0.1 H ball-mill motor (9.2 A peak rated, 560 V) gets 13.9 ms at its default calibration F of
// 10.2 A, where 4 ms asked an edge of 561 V, and 19.6 ms with a calibration at 14.4 A; the
// larger injection F decides where it is the larger. A motor a third more inductive than Table I
// keeps 4 ms, and no default exceeds the key's 1 s.
TEST(ControllerConfig, TheWindowsPeriodFollowsTheEdgesVoltage) {
  const std::string mill = R"(
[motor]
rs_ohm = 2.563
ld_H = 0.108
lq_H = 0.1
ke_V_s_per_rad = 4.0
pole_pairs = 12
continuous_current_A_rms = 6.5
rated_speed_rad_s = 6.0
inertia_kg_m2 = 60.0
[control]
nominal_dc_bus_V = 560.0
[derating]
max_current_A = 20.0
min_current_A = 2.0
)";
  const double k = core::window_constants(core::WindowKind::kModifiedBlackman).max_slope_times_tw;  // 2.04
  const double half_limit_V = 0.5 * 560.0 / std::sqrt(3.0);
  const double rated_A = 6.5 * std::sqrt(2.0);
  const ControllerConfig own = parse(mill);  // calibration.F_A = 1.11 I_rated
  EXPECT_NEAR(own.drive.injection.tw_s, k * 0.108 * (50.0 / (31.9 * std::sqrt(2.0)) * rated_A) / half_limit_V,
              1e-12);  // 13.9 ms
  const ControllerConfig c = parse(mill + "[calibration]\nF_A = 14.4\n");
  EXPECT_NEAR(c.drive.injection.tw_s, k * 0.108 * 14.4 / half_limit_V, 1e-12);  // 19.6 ms
  EXPECT_EQ(c.drive.calibration_injection.tw_s, c.drive.injection.tw_s);
  EXPECT_NEAR(core::required_injection_voltage_V(14.4, 0.108, 0.0, c.drive.injection.tw_s, c.drive.injection.window),
              half_limit_V, 1e-9);
  // The injection's F where it is the larger.
  EXPECT_NEAR(parse(mill + "[injection]\nF_A = 16.0\n").drive.injection.tw_s, k * 0.108 * 16.0 / half_limit_V, 1e-12);
  // A stated period wins.
  EXPECT_EQ(parse(mill + "[injection]\nTw_s = 0.01\n").drive.injection.tw_s, 0.01);
  // An edge no period of the key's range allows: its longest, 1 s.
  std::string henry = mill;
  henry.replace(henry.find("ld_H = 0.108"), 12, "ld_H = 1.0");
  henry.replace(henry.find("lq_H = 0.1"), 10, "lq_H = 1.0");
  henry.replace(henry.find("nominal_dc_bus_V = 560.0"), 24, "nominal_dc_bus_V = 60.0");
  EXPECT_EQ(parse(henry).drive.injection.tw_s, 1.0);  // 1 H on a 60 V bus: 1.2 s by the rule
  // Table I's motor with a third more inductance: 3.97 ms by the rule, the paper's 4 ms kept.
  EXPECT_EQ(parse("[motor]\nld_H = 7.3e-3\nlq_H = 7.3e-3\n").drive.injection.tw_s, 0.004);
}

// A small servo (1.6 ohm, 4 A RMS continuous) gets a window around its own resistance and
// injection currents sized to its own rating, where the Table I numbers would never calibrate
// and would inject nine times its rated current.
TEST(ControllerConfig, ServoMotorGetsDefaultsOfItsOwn) {
  const ControllerConfig c = parse(R"(
[motor]
rs_ohm = 1.6
continuous_current_A_rms = 4.0
ld_H = 12e-3
lq_H = 12e-3
ke_V_s_per_rad = 0.6
pole_pairs = 4
inertia_kg_m2 = 2e-4
[derating]
max_current_A = 15.0
min_current_A = 2.0
)");
  const core::DriveConfig& d = c.drive;
  const double rated_A = 4.0 * std::sqrt(2.0);  // 5.66 A peak
  EXPECT_NEAR(d.injection.rs_min_ohm, 1.6 * 0.09 / 0.133, 1e-12);  // 1.08 ohm (about -57 C)
  EXPECT_NEAR(d.injection.rs_max_ohm, 1.6 * 0.27 / 0.133, 1e-12);  // 3.25 ohm (about 287 C)
  EXPECT_LT(d.injection.rs_min_ohm, 1.6);
  EXPECT_GT(d.injection.rs_max_ohm, 1.6);
  EXPECT_NEAR(d.injection.f_A, rated_A * 35.0 / (31.9 * std::sqrt(2.0)), 1e-12);   // 4.39 A
  EXPECT_NEAR(d.injection.f_min_A, rated_A * 5.0 / (31.9 * std::sqrt(2.0)), 1e-12);  // 0.63 A
  EXPECT_NEAR(d.injection.max_load_change_A, rated_A * 1.5 / (31.9 * std::sqrt(2.0)), 1e-12);  // 0.19 A
  EXPECT_NEAR(c.calibration_f_A, rated_A * 50.0 / (31.9 * std::sqrt(2.0)), 1e-12);  // 6.27 A
  // The speed-change guard in proportion to Rs / Lq: 133 /s against Table I's 24.2 /s.
  EXPECT_NEAR(d.injection.max_speed_change_rad_s, 3.0 * (1.6 / 12e-3) / (0.133 / 5.5e-3), 1e-12);  // 16.5 rad/s
  EXPECT_LT(d.injection.f_A, rated_A);
  EXPECT_LT(c.calibration_f_A, d.derating.max_current_A);
  // Every component's copy of the motor model is the servo's.
  EXPECT_EQ(d.current.rs_ohm, 1.6);
  EXPECT_EQ(d.injection.rs_nominal_ohm, 1.6);
  EXPECT_EQ(d.calibration_injection.rs_nominal_ohm, 1.6);
  EXPECT_EQ(d.baseline.initial_rs_ohm, 1.6);
  EXPECT_EQ(d.speed.inertia_kg_m2, 2e-4);
  EXPECT_EQ(d.calibration.rs0_ohm, 1.6);
}

// The speed loop's gain, J x its bandwidth, turns the PLL's speed noise from the encoder's
// rounding into torque demand (core::speed_loop_quantisation_torque_Nm). A 12.6 kg m^2
// centrifuge on a 14-bit encoder made 52 N m RMS of a 99 N m rating at the default 60 rad/s and
// tripped braking; Table I's 0.0084 kg m^2 makes 0.05 % of its rating there. Above 5 % the
// loader warns, naming the bandwidth that keeps it at 5 %; the bandwidth stays as configured.
bool any_names(const std::vector<std::string>& warnings, std::string_view text) {
  return std::any_of(warnings.begin(), warnings.end(), [&](const std::string& w) { return w.find(text) != std::string::npos; });
}

TEST(ControllerConfig, ASpeedLoopThatAmplifiesTheEncodersRoundingIsWarnedAbout) {
  const ControllerConfig table_i = default_controller_config();
  EXPECT_EQ(table_i.drive.speed.bandwidth_rad_s, 60.0);
  EXPECT_FALSE(any_names(configuration_warnings(table_i), "speed_bandwidth_rad_s"));

  constexpr std::string_view kCentrifuge = R"(
[motor]
rs_ohm = 0.1906
ld_H = 4.95e-3
lq_H = 4.7e-3
ke_V_s_per_rad = 2.293
pole_pairs = 6
continuous_current_A_rms = 25.0
rated_speed_rad_s = 157.0
inertia_kg_m2 = 12.6
[control]
period_s = 1.25e-4
nominal_dc_bus_V = 650.0
)";
  const ControllerConfig c = parse(kCentrifuge);
  const core::DriveConfig& d = c.drive;
  EXPECT_EQ(d.speed.bandwidth_rad_s, 60.0) << "warned about, not changed";
  const double rated_Nm = core::torque_constant_dq_Nm_per_A(d.motor) * core::continuous_current_peak_A(d.motor);
  EXPECT_NEAR(speed_loop_rated_torque_Nm(d), rated_Nm, 1e-12);
  // 5.7 rad/s keeps the noise at 5 % of the rating; at 60 rad/s it is 52 %.
  const double quiet_rad_s = quantisation_limited_speed_bandwidth_rad_s(d);
  EXPECT_GT(quiet_rad_s, 5.0);
  EXPECT_LT(quiet_rad_s, 6.0);
  EXPECT_NEAR(core::speed_loop_quantisation_torque_Nm(12.6, quiet_rad_s, 300.0, 1.25e-4, 14),
              kSpeedLoopQuantisationTorqueShare * rated_Nm, 1e-9 * rated_Nm);
  const std::vector<std::string> w = configuration_warnings(c);
  EXPECT_TRUE(any_names(w, "controller.control.speed_bandwidth_rad_s = 60 rad/s: the speed loop's gain "
                           "(motor.inertia_kg_m2 = 12.6 kg m^2 x the bandwidth) turns the 14-bit encoder's rounding, "
                           "read through the PLL's speed (control.pll_bandwidth_rad_s = 300 rad/s), into 52.1 N m RMS of "
                           "torque demand, 52.5 % of the rated 99.3 N m; it would be 5 %, where this warning starts, at 5.72 "
                           "rad/s"))
      << (w.empty() ? "" : w.front());

  // A finer encoder or a slower PLL allows more: 16 bits, four times the bandwidth; the PLL at
  // 60 rad/s, its 2 wn (1 + wn T) less.
  EXPECT_NEAR(quantisation_limited_speed_bandwidth_rad_s(parse(std::string(kCentrifuge) + "[sensors]\nencoder_bits = 16\n").drive),
              4.0 * quiet_rad_s, 1e-9);
  EXPECT_NEAR(quantisation_limited_speed_bandwidth_rad_s(parse(std::string(kCentrifuge) + "pll_bandwidth_rad_s = 60.0\n").drive),
              quiet_rad_s * (300.0 * (1.0 + 300.0 * 1.25e-4)) / (60.0 * (1.0 + 60.0 * 1.25e-4)), 1e-9);

  // The newcomer's 15 rad/s is still 13 %; 5 rad/s passes without a warning.
  EXPECT_TRUE(any_names(configuration_warnings(parse(std::string(kCentrifuge) + "speed_bandwidth_rad_s = 15.0\n")),
                        "speed_bandwidth_rad_s = 15 rad/s: the speed loop's gain (motor.inertia_kg_m2 = 12.6 kg m^2 x the "
                        "bandwidth) turns the 14-bit encoder's rounding, read through the PLL's speed "
                        "(control.pll_bandwidth_rad_s = 300 rad/s), into 13 N m RMS of torque demand, 13.1 % of the rated"));
  EXPECT_FALSE(any_names(configuration_warnings(parse(std::string(kCentrifuge) + "speed_bandwidth_rad_s = 5.0\n")),
                         "speed_bandwidth_rad_s"));
}

// A shaft fan's standstill share or exponent without the fan's speed describes a fan the model
// does not use: told, with the keys named; the fan given whole, or not at all, is not.
TEST(ControllerConfig, AShaftFanWithoutItsSpeedIsWarnedAbout) {
  const std::string_view text = "but thermal.fan_speed_rad_s is 0 (no shaft fan): they are not used";
  EXPECT_FALSE(any_names(configuration_warnings(default_controller_config()), text));
  const ControllerConfig share_only = parse("[thermal]\nfan_standstill_share = 0.4\n");
  EXPECT_EQ(share_only.drive.thermal.fan_speed_rad_s, 0.0);
  EXPECT_EQ(core::housing_cooling_share(share_only.drive.thermal, 0.0), 1.0) << "no fan modelled";
  EXPECT_TRUE(any_names(configuration_warnings(share_only),
                        "controller.thermal.fan_standstill_share = 0.4 and fan_exponent = 0.8 describe a shaft fan, but "
                        "thermal.fan_speed_rad_s is 0 (no shaft fan): they are not used"));
  EXPECT_TRUE(any_names(configuration_warnings(parse("[thermal]\nfan_exponent = 1.0\n")), text));
  const ControllerConfig whole = parse("[thermal]\nfan_speed_rad_s = 314.0\nfan_standstill_share = 0.4\n");
  EXPECT_FALSE(any_names(configuration_warnings(whole), text));
  EXPECT_DOUBLE_EQ(core::housing_cooling_share(whole.drive.thermal, 0.0), 0.4);
  // The fan's speed far from the rated speed (Table I's 314 rad/s): 50 (its Hz) is told, half and
  // twice the rated speed are not.
  const std::string_view far = "lies far from controller.motor.rated_speed_rad_s = 314 rad/s";
  EXPECT_FALSE(any_names(configuration_warnings(whole), far));
  EXPECT_TRUE(any_names(configuration_warnings(parse("[thermal]\nfan_speed_rad_s = 50.0\n")),
                        "controller.thermal.fan_speed_rad_s = 50 rad/s lies far from"));
  EXPECT_TRUE(any_names(configuration_warnings(parse("[thermal]\nfan_speed_rad_s = 3000.0\n")), far));
  EXPECT_FALSE(any_names(configuration_warnings(parse("[thermal]\nfan_speed_rad_s = 157.0\n")), far));
  EXPECT_FALSE(any_names(configuration_warnings(parse("[thermal]\nfan_speed_rad_s = 628.0\n")), far));
}

// The filter's step is checked against its model's fastest time constant with a shaft fan's
// largest share (its speed held at twice the fan's): a fan whose share would make that mode
// faster than the step allows is refused at load, where an unbounded share diverged in the run
// (a fan speed of 1 rad/s with exponent 2: the estimate at 3e161 C by 22 s).
TEST(ControllerConfig, AShaftFansLargestShareBoundsTheFiltersStep) {
  core::ThermalModelConfig t;
  t.fan_speed_rad_s = 1.0;
  t.fan_exponent = 2.0;
  t.fan_standstill_share = 0.35;
  EXPECT_DOUBLE_EQ(core::housing_cooling_share(t, 314.0), 0.35 + 0.65 * 4.0) << "held at twice the fan's speed";
  EXPECT_DOUBLE_EQ(core::housing_cooling_share(t, 2.0), core::housing_cooling_share(t, 314.0));
  core::ThermalModelConfig plain;
  EXPECT_LT(core::thermal_model_fastest_time_constant_s(t), core::thermal_model_fastest_time_constant_s(plain));
  // At an acceleration that takes the step past half the fan's fastest constant, and not past
  // half the plain model's: refused with the fan, accepted without.
  const double between = 0.5 * (core::thermal_model_fastest_time_constant_s(t) +
                                core::thermal_model_fastest_time_constant_s(plain));
  const double acceleration = core::kMaxThermalStepPerTimeConstant * between / 0.01;  // update_s 0.01 s
  const std::string keys = "[thermal]\nupdate_s = 0.01\nacceleration = " + std::to_string(acceleration) + "\n";
  EXPECT_NO_THROW((void)parse(keys));
  EXPECT_THROW((void)parse(keys + "fan_speed_rad_s = 1.0\nfan_exponent = 2.0\n"), ConfigError);
}

// A method that does not hold the torque or does not cancel the bridge's even error, on a
// machine configured as salient (a torque budget), is warned about at load (measured on the
// 30 mohm IPM: docs/accuracy.md, "The robustness suite under the other methods"); fixed-magnitude
// bipolar, a round rotor, and a drive that does not inject are not.
TEST(ControllerConfig, AMethodThatMisleadsOnASalientMachineIsWarnedAbout) {
  constexpr std::string_view kSalient = "[injection]\nmax_torque_disturbance_Nm = 1.5\n";
  const std::string_view text = "on a machine configured as salient (injection.max_torque_disturbance_Nm = 1.5 N m)";
  EXPECT_FALSE(any_names(configuration_warnings(parse(kSalient)), text)) << "fixed-magnitude bipolar, the default";
  EXPECT_TRUE(any_names(configuration_warnings(parse(std::string(kSalient) + "method = \"fixed-angle\"\n")),
                        "controller.injection: method = \"fixed-angle\", separation = \"bipolar\" " + std::string(text)));
  // DC injection has no separation to speak of, and its own reason.
  const std::vector<std::string> dc = configuration_warnings(parse(std::string(kSalient) + "method = \"dc\"\n"));
  EXPECT_TRUE(any_names(dc, "controller.injection: method = \"dc\" " + std::string(text) + ": DC injection holds no torque"));
  EXPECT_FALSE(any_names(dc, "separation"));
  EXPECT_TRUE(any_names(configuration_warnings(parse(std::string(kSalient) + "separation = \"unipolar\"\n")),
                        "method = \"fixed-magnitude\", separation = \"unipolar\" " + std::string(text)));
  // The same text for a method picked at run time (the daemon logs it).
  const core::DriveConfig salient = parse(kSalient).drive;
  EXPECT_NE(salient_method_warning(salient, core::InjectionMethod::kFixedAngle, core::Separation::kUnipolar)
                .find("method = \"fixed-angle\", separation = \"unipolar\" " + std::string(text)),
            std::string::npos);
  EXPECT_EQ(salient_method_warning(salient, core::InjectionMethod::kFixedMagnitude, core::Separation::kBipolar), "");
  EXPECT_EQ(salient_method_warning(salient, core::InjectionMethod::kNone, core::Separation::kUnipolar), "");
  EXPECT_EQ(salient_method_warning(default_controller_config().drive, core::InjectionMethod::kDc, core::Separation::kBipolar),
            "")
      << "a round rotor";
  // A round rotor (no budget) with any method, and a salient one whose estimator does not inject.
  EXPECT_FALSE(any_names(configuration_warnings(parse("[injection]\nmethod = \"fixed-angle\"\n")), "configured as salient"));
  EXPECT_FALSE(any_names(configuration_warnings(parse(std::string(kSalient) + "method = \"fixed-angle\"\n"
                                                                                  "[estimator]\nkind = \"none\"\n")),
                         "configured as salient"));
}

// A salient machine with torque-neutral pulses and no flux map is warned about, with what an
// error of the incremental Lq reads as in Rs at the rated point: w_e Lq iq |Lq - Ld| / (psi Rs).
// The robustness suite's 30 mohm IPM as commissioned: 4 x 314 rad/s, Lq 0.4275 mH, 141.4 A
// peak, Lq - Ld 0.1525 mH, psi 0.4925 sqrt 2 / sqrt 3 / 4 = 0.1005 Wb, Rs 31.5 mOhm: 3.66.
// A map or its rated point, pulses on the d axis alone, no budget, and a saliency too small to
// matter are not warned about.
TEST(ControllerConfig, ASalientMachineWithoutItsFluxMapIsWarnedAbout) {
  constexpr std::string_view kIpm =
      "[motor]\nrs_ohm = 0.0315\nld_H = 0.275e-3\nlq_H = 0.4275e-3\nke_V_s_per_rad = 0.4925\npole_pairs = 4\n"
      "continuous_current_A_rms = 100.0\n";
  const std::string budget = "[control]\nnominal_dc_bus_V = 320.0\n[injection]\nmax_torque_disturbance_Nm = 1.5\n";
  const std::string rated = "rated_speed_rad_s = 314.0\n";
  const ControllerConfig ipm = parse(std::string(kIpm) + rated + budget);
  const double psi = 0.4925 * std::sqrt(2.0) / std::sqrt(3.0) / 4.0;
  const double expected = 4.0 * 314.0 * 0.4275e-3 * 100.0 * std::sqrt(2.0) * 0.1525e-3 / (psi * 0.0315);
  // The rated current would take the whole voltage only at about 370 rad/s, 0.95 x 320 V / sqrt 3
  // over 4 sqrt(psi^2 + (Lq iq)^2): the rated speed is taken.
  EXPECT_EQ(incremental_lq_sensitivity_speed_rad_s(ipm), 314.0);
  EXPECT_NEAR(incremental_lq_sensitivity(ipm.drive, 314.0), expected, 1e-9 * expected);
  EXPECT_NEAR(expected, 3.66, 0.01);
  const std::string_view text = "controller.motor: a salient machine (injection.max_torque_disturbance_Nm = 1.5 N m)";
  const std::vector<std::string> w = configuration_warnings(ipm);
  EXPECT_TRUE(any_names(w, text));
  EXPECT_TRUE(any_names(w, "each 1 % of that error reads as 3.7 % of Rs"));
  EXPECT_TRUE(any_names(w, "read high by the gap while the machine motors, and low by as much while it generates"));
  EXPECT_TRUE(any_names(w, "at the rated current (141 A peak) and 314 rad/s"));
  // A traction motor rated to 900 rad/s is taken where the rated current takes the voltage.
  const ControllerConfig traction = parse(std::string(kIpm) + "rated_speed_rad_s = 900.0\n" + budget);
  const double emf_speed = incremental_lq_sensitivity_speed_rad_s(traction);
  EXPECT_GT(emf_speed, 314.0);
  EXPECT_LT(emf_speed, 900.0);
  EXPECT_NEAR(incremental_lq_sensitivity(traction.drive, emf_speed), expected * emf_speed / 314.0, 1e-9 * expected);
  // A map, or its rated point alone, gives the gap.
  const std::string ipm_text = std::string(kIpm) + rated;
  EXPECT_FALSE(any_names(configuration_warnings(parse(ipm_text +
                                                      "lq_map_current_A = [70.0, 141.0]\n"
                                                      "lq_map_H = [0.42e-3, 0.405e-3]\n" + budget)),
                         text));
  EXPECT_FALSE(any_names(configuration_warnings(parse(ipm_text + "lq_rated_H = 0.405e-3\n" + budget)), text));
  // A salient rotor that does not saturate says so: its rated secant is its no-load Lq.
  EXPECT_FALSE(any_names(configuration_warnings(parse(ipm_text + "lq_rated_H = 0.4275e-3\n" + budget)), text));
  // Pulses on the d axis alone, another method, no budget, a drive that does not inject.
  EXPECT_FALSE(any_names(configuration_warnings(parse(ipm_text + budget + "torque_neutral = false\n")), text));
  EXPECT_FALSE(any_names(configuration_warnings(parse(ipm_text + budget + "method = \"fixed-angle\"\n")), text));
  EXPECT_FALSE(any_names(configuration_warnings(parse(ipm_text)), text));
  EXPECT_FALSE(any_names(configuration_warnings(parse(ipm_text + budget + "[estimator]\nkind = \"none\"\n")), text));
  // Table I's w_e Lq / Rs is 39 at its rated speed, and iq Lq / psi 0.76: a saliency of 2 % reads
  // 0.61, warned about; one of 0.3 % 0.09, and Lq = Ld 0, not.
  const auto table_i_with = [](std::string_view lq) {
    return parse("[motor]\nlq_H = " + std::string(lq) + "\n[injection]\nmax_torque_disturbance_Nm = 1.0\n");
  };
  EXPECT_NEAR(incremental_lq_sensitivity(table_i_with("5.61e-3").drive, 314.0), 0.61, 0.01);
  EXPECT_TRUE(any_names(configuration_warnings(table_i_with("5.61e-3")), "a salient machine"));
  EXPECT_LT(incremental_lq_sensitivity(table_i_with("5.5165e-3").drive, 314.0), kIncrementalLqSensitivityWarning);
  EXPECT_FALSE(any_names(configuration_warnings(table_i_with("5.5165e-3")), "a salient machine"));
  EXPECT_EQ(incremental_lq_sensitivity(table_i_with("5.5e-3").drive, 314.0), 0.0);
  EXPECT_FALSE(any_names(configuration_warnings(table_i_with("5.5e-3")), "a salient machine"));
}

// A drive whose pairs are mostly rejected as speed or load changes is told why it measures
// rarely: at least 20 pairs judged (recorded to their end), at least half of them so rejected.
// Pairs skipped before they began and aborted ones are not judged. Without a torque budget the
// salient rotor is named as a cause with the commissioned Lq / Ld, whatever it is (commissioning
// errors can hide a saliency); with one, only the duty cycle is.
TEST(ControllerConfig, PairsMostlyRejectedAsSpeedOrLoadChangesAreExplained) {
  using core::PairOutcome;
  const auto counts = [](std::uint32_t accepted, std::uint32_t speed, std::uint32_t load, std::uint32_t skipped = 0,
                         std::uint32_t aborted = 0) {
    core::OutcomeCounts c{};
    c[static_cast<std::size_t>(PairOutcome::kAccepted)] = accepted;
    c[static_cast<std::size_t>(PairOutcome::kRejectedSpeedChange)] = speed;
    c[static_cast<std::size_t>(PairOutcome::kRejectedLoadChange)] = load;
    c[static_cast<std::size_t>(PairOutcome::kRejectedVoltageHeadroom)] = skipped;
    c[static_cast<std::size_t>(PairOutcome::kAborted)] = aborted;
    return c;
  };
  const core::DriveConfig round = default_controller_config().drive;  // Ld = Lq by default
  EXPECT_EQ(pair_rejection_advice(counts(9, 6, 4), round), "") << "19 judged: too few";
  EXPECT_EQ(pair_rejection_advice(counts(11, 6, 3), round), "") << "9 of 20: under half";
  const std::string half = pair_rejection_advice(counts(10, 6, 4), round);
  EXPECT_NE(half.find("10 of 20 injection pairs judged were rejected because the speed (6) or the load (4) changed"),
            std::string::npos)
      << half;
  EXPECT_NE(half.find("injection.max_load_change_A"), std::string::npos) << half;
  EXPECT_NE(half.find("if the rotor has interior or inset magnets whatever the commissioned Lq / Ld (1) says"),
            std::string::npos)
      << half;
  // Skipped and aborted pairs are not judged: counted, 10 of 20 would have been half.
  EXPECT_EQ(pair_rejection_advice(counts(0, 6, 4, 10, 0), round), "");
  EXPECT_EQ(pair_rejection_advice(counts(0, 6, 4, 0, 10), round), "");
  EXPECT_NE(pair_rejection_advice(counts(5, 10, 5, 100, 100), round).find("15 of 20 injection pairs judged"),
            std::string::npos);
  // The other rejections are judged: 10 moved of 10 + 10 residual is half.
  core::OutcomeCounts others = counts(0, 5, 5);
  others[static_cast<std::size_t>(PairOutcome::kRejectedResidual)] = 4;
  others[static_cast<std::size_t>(PairOutcome::kRejectedImplausible)] = 2;
  others[static_cast<std::size_t>(PairOutcome::kRejectedVoltageSaturation)] = 2;
  others[static_cast<std::size_t>(PairOutcome::kRejectedIllConditioned)] = 2;
  others[static_cast<std::size_t>(PairOutcome::kRejectedCurrentLimit)] = 7;
  others[static_cast<std::size_t>(PairOutcome::kSkippedTorqueDisturbance)] = 7;
  EXPECT_NE(pair_rejection_advice(others, round).find("10 of 20 "), std::string::npos);
  others[static_cast<std::size_t>(PairOutcome::kRejectedResidual)] = 5;
  EXPECT_EQ(pair_rejection_advice(others, round), "") << "10 of 21";
  const core::DriveConfig budget = parse("[injection]\nmax_torque_disturbance_Nm = 1.5\n").drive;
  const std::string with_budget = pair_rejection_advice(counts(2, 30, 0), budget);
  EXPECT_NE(with_budget.find("30 of 32"), std::string::npos) << with_budget;
  EXPECT_EQ(with_budget.find("salient"), std::string::npos) << "the torque budget is there already: " << with_budget;
}

// The missing loss's prior and random walk follow the cooling path's conductance: a small
// pump (6.4 K/W to ambient, about 7 W of loss) gets 0.98 W, not the Table I machine's 50 W,
// which let it learn a missing loss larger than its whole loss.
TEST(ControllerConfig, TheMissingLossPriorFollowsTheCoolingPath) {
  const ControllerConfig c = parse("[thermal]\nhousing_to_ambient_K_W = 6.4\n");
  EXPECT_NEAR(c.drive.thermal.initial_loss_error_std_W, 50.0 * 0.125 / 6.4, 1e-12);
  EXPECT_NEAR(c.drive.thermal.loss_error_process_std_W_per_sqrt_s, 0.5 * 0.125 / 6.4, 1e-12);
  const ControllerConfig g =
      parse("[thermal]\nhousing_to_ambient_K_W = 6.4\ninitial_loss_error_std_W = 3\nloss_error_process_std_W_per_sqrt_s = 0.1\n");
  EXPECT_EQ(g.drive.thermal.initial_loss_error_std_W, 3.0);
  EXPECT_EQ(g.drive.thermal.loss_error_process_std_W_per_sqrt_s, 0.1);
}

// The voltage margin follows the bus: a 48 V drive keeps 1.1 V free of its 26 V limit, not
// the Table I drive's 15 V (58 % of it: every pair at speed would be a field-weakening pair).
TEST(ControllerConfig, HeadroomMarginFollowsTheBus) {
  const ControllerConfig low = parse("[control]\nnominal_dc_bus_V = 48\n");
  EXPECT_NEAR(low.drive.injection.headroom_margin_V, 15.0 * 48.0 / 650.0, 1e-12);
  EXPECT_EQ(low.drive.calibration_injection.headroom_margin_V, low.drive.injection.headroom_margin_V);
  EXPECT_EQ(parse("[control]\nnominal_dc_bus_V = 48\n[injection]\nheadroom_margin_V = 3\n").drive.injection.headroom_margin_V,
            3.0);
  // A margin that takes the whole voltage limit (0.95 x 48 / sqrt(3) = 26.3 V).
  const std::string e = error_of("[control]\nnominal_dc_bus_V = 48\n[injection]\nheadroom_margin_V = 27\n");
  EXPECT_EQ(e.rfind("drive.toml:4: injection.headroom_margin_V (27 V) must be below the voltage limit at the bus "
                    "control.nominal_dc_bus_V (48 V, drive.toml:2), 26.3272 V", 0), 0U) << e;
  EXPECT_EQ(error_of("[control]\nnominal_dc_bus_V = 48\n[injection]\nheadroom_margin_V = 26\n"), "");
}

// The field-weakening loop must be well inside the current loop's bandwidth (2000 rad/s here).
TEST(ControllerConfig, TheFieldWeakeningLoopIsSlowerThanTheCurrentLoop) {
  const std::string e = error_of("[control]\nfield_weakening = true\nfield_weakening_bandwidth_rad_s = 1500\n");
  EXPECT_EQ(e.rfind("drive.toml:3: control.field_weakening_bandwidth_rad_s (1500 rad/s) must be at most half of "
                    "control.current_bandwidth_rad_s (2000 rad/s",
                    0),
            0U)
      << e;
  EXPECT_EQ(error_of("[control]\nfield_weakening = true\nfield_weakening_bandwidth_rad_s = 1000\n"), "");
  // Its bound follows the motor: psi / Ld (Table I: 58.9 A) below the current limit.
  const ControllerConfig c = parse("[control]\nfield_weakening = true\n");
  EXPECT_TRUE(c.drive.field_weakening.enabled);
  EXPECT_NEAR(c.drive.field_weakening.max_current_A, core::flux_linkage_Wb(c.drive.motor) / c.drive.motor.ld_H, 1e-9);
  EXPECT_LT(c.drive.field_weakening.max_current_A, c.drive.derating.max_current_A);
}

// A flux map's secant Lq at the rated current: saturation lowers it, so it lies between half
// of the commissioned Lq and Lq itself; it reaches the scheduler with the rated current.
TEST(ControllerConfig, RatedCurrentLqIsCheckedAgainstLq) {
  const ControllerConfig c = parse("[motor]\nlq_rated_H = 5.0e-3\n");
  EXPECT_EQ(c.drive.injection.lq_rated_H, 5.0e-3);
  EXPECT_EQ(c.drive.calibration_injection.lq_rated_H, 5.0e-3);
  EXPECT_NEAR(c.drive.injection.rated_current_A, 31.9 * std::sqrt(2.0), 1e-9);
  EXPECT_EQ(parse("").drive.injection.lq_rated_H, 0.0);
  const std::string high = error_of("[motor]\nlq_H = 5.5e-3\nlq_rated_H = 6e-3\n");
  EXPECT_EQ(high.rfind("drive.toml:3: motor.lq_rated_H (0.006 H) must lie between half of motor.lq_H (0.0055 H, drive.toml:2) "
                       "and it", 0), 0U) << high;
  EXPECT_EQ(error_of("[motor]\nlq_rated_H = 2e-3\n").rfind("drive.toml:2: motor.lq_rated_H (0.002 H) must lie between half of motor.lq_H", 0),
            0U);
  EXPECT_EQ(error_of("[motor]\nlq_rated_H = -1e-3\n").rfind("drive.toml:2: motor.lq_rated_H: must be", 0), 0U);
  // The bounds themselves are accepted (no saturation; half of Lq at the rated current when the
  // rated current is the limit).
  EXPECT_EQ(error_of("[motor]\nlq_H = 5.5e-3\nlq_rated_H = 5.5e-3\n"), "");
  EXPECT_EQ(error_of("[motor]\nlq_H = 5.5e-3\nlq_rated_H = 2.75e-3\n[derating]\nmax_current_A = 45.1134\n"), "");
  // Half of Lq at the rated current with the limit at twice it: the curve would reach
  // 5.5 - 2.75 x 4 mH at the limit.
  const std::string far = error_of("[motor]\nlq_H = 5.5e-3\nlq_rated_H = 3e-3\n[derating]\nmax_current_A = 90.2\n");
  EXPECT_EQ(far.rfind("drive.toml:3: motor.lq_rated_H (0.003 H) at the rated current (45.1134 A peak) implies a secant Lq of ", 0), 0U)
      << far;
  EXPECT_NE(far.find("derating.max_current_A (90.2 A, drive.toml:5)"), std::string::npos) << far;
  EXPECT_EQ(c.drive.calibration_injection.rated_current_A, c.drive.injection.rated_current_A);
}

// A flux map of several points: two lists of one length, the currents ascending, every secant
// between half of Lq and Lq; it replaces the one point of motor.lq_rated_H (giving both is an
// error) and reaches both of the scheduler's configurations.
TEST(ControllerConfig, AFluxMapIsCheckedAsAWhole) {
  const ControllerConfig c =
      parse("[motor]\nlq_H = 5.5e-3\nlq_map_current_A = [20, 40, 60]\nlq_map_H = [5.45e-3, 5.3e-3, 5.0e-3]\n");
  for (const core::InjectionConfig* i : {&c.drive.injection, &c.drive.calibration_injection}) {
    ASSERT_EQ(i->lq_map.points, 3);
    EXPECT_EQ(i->lq_map.current_A[2], 60.0);
    EXPECT_EQ(i->lq_map.secant_H[1], 5.3e-3);
  }
  EXPECT_EQ(parse("").drive.injection.lq_map.points, 0);
  EXPECT_EQ(parse("[motor]\nlq_map_current_A = []\nlq_map_H = []\n").drive.injection.lq_map.points, 0);
  const std::string lengths = error_of("[motor]\nlq_map_current_A = [20, 40]\nlq_map_H = [5.4e-3]\n");
  EXPECT_EQ(lengths, "drive.toml:3: motor.lq_map_H has 1 points and motor.lq_map_current_A 2: one secant inductance per current")
      << lengths;
  const std::string both = error_of("[motor]\nlq_rated_H = 5e-3\nlq_map_current_A = [20]\nlq_map_H = [5.4e-3]\n");
  EXPECT_NE(both.find("motor.lq_map_H and motor.lq_rated_H are both given"), std::string::npos) << both;
  const std::string order = error_of("[motor]\nlq_map_current_A = [40, 20]\nlq_map_H = [5.4e-3, 5.3e-3]\n");
  EXPECT_EQ(order, "drive.toml:2: motor.lq_map_current_A must ascend: point 1 (20 A) is not above point 0 (40 A)") << order;
  const std::string high = error_of("[motor]\nlq_H = 5.5e-3\nlq_map_current_A = [20, 40]\nlq_map_H = [5.4e-3, 5.6e-3]\n");
  EXPECT_EQ(high.rfind("drive.toml:4: motor.lq_map_H point 1 (0.0056 H at 40 A) must lie between half of motor.lq_H "
                       "(0.0055 H, drive.toml:2)", 0), 0U) << high;
  EXPECT_EQ(error_of("[motor]\nlq_map_current_A = [20, nan]\nlq_map_H = [5.4e-3, 5.3e-3]\n")
                .rfind("drive.toml:2: motor.lq_map_current_A", 0), 0U);
  // Only one of the two lists, more than eight points, a map that rises with the current or ends
  // at lq_H, a point at 0 A (lq_H is the map there): each named, none accepted.
  EXPECT_EQ(error_of("[motor]\nlq_map_H = [5.4e-3]\n"),
            "drive.toml:2: motor.lq_map_H has 1 points and motor.lq_map_current_A 0: one secant inductance per current");
  const std::string nine =
      error_of("[motor]\nlq_map_current_A = [1, 2, 3, 4, 5, 6, 7, 8, 9]\nlq_map_H = [5.4e-3, 5.3e-3]\n");
  EXPECT_EQ(nine.rfind("drive.toml:2: motor.lq_map_current_A: expected 0 to 8 values, got 9", 0), 0U) << nine;
  const std::string rises = error_of("[motor]\nlq_H = 5.5e-3\nlq_map_current_A = [20, 40]\nlq_map_H = [5.3e-3, 5.4e-3]\n");
  EXPECT_EQ(rises.rfind("drive.toml:4: motor.lq_map_H must not rise with the current: point 1 (0.0054 H) is above point 0", 0),
            0U) << rises;
  const std::string flat = error_of("[motor]\nlq_H = 5.5e-3\nlq_map_current_A = [20, 40]\nlq_map_H = [5.5e-3, 5.5e-3]\n");
  EXPECT_NE(flat.find("motor.lq_map_H's last point (0.0055 H) equals motor.lq_H"), std::string::npos) << flat;
  const std::string zero = error_of("[motor]\nlq_map_current_A = [0, 40]\nlq_map_H = [5.5e-3, 5.3e-3]\n");
  EXPECT_EQ(zero.rfind("drive.toml:2: motor.lq_map_current_A", 0), 0U) << zero;
  // The map's last segment, extrapolated to the current limit (80 A here), must keep the secant
  // above half of Lq: from 5.5 mH to 4 mH between 30 and 40 A falls far below it by 80 A.
  const std::string steep = error_of(
      "[motor]\nlq_H = 5.5e-3\nlq_map_current_A = [30, 40]\nlq_map_H = [5.4e-3, 4.0e-3]\n[derating]\nmax_current_A = 80\n");
  EXPECT_EQ(steep.rfind("drive.toml:4: motor.lq_map_H, extrapolated from its last point, implies a secant Lq of ", 0), 0U) << steep;
}

// The controller's components take the motor model from DriveConfig::motor whatever the
// sub-configurations say: the copies cannot disagree.
TEST(ControllerConfig, DriveControllerDerivesFromTheMotor) {
  core::DriveConfig d = default_controller_config().drive;
  d.motor.ld_H = 7e-3;
  d.motor.rs_ohm = 0.2;
  d.current.ld_H = 1.0;  // stale copies
  d.injection.rs_nominal_ohm = 1.0;
  const core::DriveController controller(d);
  EXPECT_EQ(controller.config().current.ld_H, 7e-3);
  EXPECT_EQ(controller.config().injection.ld_H, 7e-3);
  EXPECT_EQ(controller.config().calibration_injection.ld_H, 7e-3);
  EXPECT_EQ(controller.config().baseline.ld_H, 7e-3);
  EXPECT_EQ(controller.config().injection.rs_nominal_ohm, 0.2);
  EXPECT_EQ(controller.config().current.rs_ohm, 0.2);
}

// A stored calibration's bridge voltage is the estimator's Vx prior (both injections'); without
// one the configured prior holds. Given without its error bar it would be ignored: refused.
TEST(ControllerConfig, AStoredBridgeVoltageIsTheVxPrior) {
  const ControllerConfig c = parse("[calibration]\nvx_V = 7.508\nvx_std_V = 0.024\n");
  core::DriveController stored(c.drive);
  EXPECT_EQ(stored.vx_V(), 7.508);
  EXPECT_DOUBLE_EQ(stored.vx_std_V(), 0.024);
  // The configured guess stays the configuration's: a calibration run starts from it (it
  // learns Vx afresh), and one that does not complete puts the stored Vx back.
  EXPECT_EQ(stored.config().injection.vx_initial_std_V, 3.0);
  stored.start_calibration(25.0);
  EXPECT_EQ(stored.vx_V(), c.drive.injection.vx_initial_V);
  EXPECT_DOUBLE_EQ(stored.vx_std_V(), 3.0);
  stored.abort_calibration();
  EXPECT_EQ(stored.vx_V(), 7.508);
  EXPECT_DOUBLE_EQ(stored.vx_std_V(), 0.024);
  // Learned on another bus than the nominal one (650 V): its error bar is the one there, and at
  // the nominal bus the bus slope's prior times the distance adds (a fifth of 0.9 us x 10 kHz).
  const ControllerConfig off_bus = parse("[calibration]\nvx_V = 7.508\nvx_std_V = 0.024\nvx_bus_V = 560\n");
  const core::DriveController low(off_bus.drive);
  const double slope_std = 0.2 * 0.9e-6 * 1e4;
  EXPECT_NEAR(low.vx_std_V(), std::hypot(0.024, 90.0 * slope_std), 1e-12);
  EXPECT_NEAR(low.vx_std_at_V(-90.0), 0.024, 1e-12) << "at the bus it was learned on, its own error bar";
  const ControllerConfig none = parse("");
  const core::DriveController guess(none.drive);
  EXPECT_EQ(guess.vx_V(), none.drive.injection.vx_initial_V);
  EXPECT_DOUBLE_EQ(guess.vx_std_V(), 3.0);
  const std::string alone = error_of("[calibration]\nvx_V = 7.5\n");
  EXPECT_EQ(alone.rfind("drive.toml:2: calibration.vx_V (7.5 V) needs its standard error calibration.vx_std_V (0 V, its default)", 0),
            0U)
      << alone;
  EXPECT_EQ(error_of("[calibration]\nvx_std_V = -0.1\n").rfind("drive.toml:2: calibration.vx_std_V: must be", 0), 0U);
  const std::string bar = error_of("[calibration]\nvx_std_V = 0.05\n");
  EXPECT_EQ(bar.rfind("drive.toml:2: calibration.vx_std_V (0.05 V) is the standard error of a stored calibration.vx_V, which is not given", 0),
            0U)
      << bar;
}

TEST(ControllerConfig, PrefixedForScenarios) {
  try {
    (void)parse_controller_config(toml::parse(std::string_view{"[injection]\nF_A = -1\n"}, std::string_view{"scen.toml"}), "scen.toml", {}, "controller.");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), "scen.toml:2: controller.injection.F_A: must be in (0, 1000], got -1");
  }
}

TEST(ControllerConfig, SchemaCoversEverySection) {
  const std::vector<std::string> keys = controller_schema().keys();
  for (const std::string& section : controller_sections()) {
    bool found = false;
    for (const std::string& k : keys) found = found || k.rfind(section + ".", 0) == 0;
    EXPECT_TRUE(found) << section;
  }
  for (const std::string& k : keys) {
    bool owned = false;
    for (const std::string& section : controller_sections()) owned = owned || k.rfind(section + ".", 0) == 0;
    EXPECT_TRUE(owned) << k;
  }
}

}  // namespace
}  // namespace pmsm::app
