// Plant configuration: shipped profiles parse, bad files name the key, defaults are Table I.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "pmsm/plant/config.hpp"
#include "scratch_dir.hpp"

namespace pmsm::plant {
namespace {

const std::filesystem::path kProfiles =
    std::filesystem::path(PMSM_SOURCE_DIR) / "plant-emulator" / "profiles";

// Parses `text` and returns the error message, or "" when it parsed.
std::string error_of(const std::string& text,
                     const std::filesystem::path& base = std::filesystem::path()) {
  try {
    (void)parse_plant_config(text, "test.toml", base);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

// The winding's electrical time constant against the integration's step: RK4 on a period
// (or a substep) must follow it, or the model runs away (a 400 ohm winding on the reference's
// inductances reached 78 million C; 0.1 nH gave NaN currents).
TEST(plant_config, TheWindingsTimeConstantMustSpanTwoIntegrationSteps) {
  const std::string runaway = error_of("[motor]\nrs_ohm = 100.0\n");
  EXPECT_NE(runaway.find("motor.rs_ohm: the winding's electrical time constant"), std::string::npos) << runaway;
  EXPECT_NE(runaway.find("2.75e-05 s, is shorter than two integration steps"), std::string::npos) << runaway;
  EXPECT_NE(runaway.find("raise simulation.substeps to 8"), std::string::npos) << runaway;
  const std::string tiny = error_of("[motor]\nld_H = 1e-9\n[saturation]\nenabled = false\n");
  EXPECT_NE(tiny.find("raise simulation.substeps to its 64 and lower the PWM period"), std::string::npos) << tiny;
  // At the inductance's line, the resistance being its default, and naming the inductance.
  EXPECT_EQ(tiny.rfind("test.toml:2: motor.ld_H: the winding's electrical time constant, the smallest inductance "
                       "(motor.ld_H = 1e-09 H) over twice motor.rs_ohm (0.133 ohm)",
                       0),
            0U)
      << tiny;
  // 0.3 mH over twice 1 ohm is 0.15 ms: not two 100 us steps, but two 50 us substeps.
  const std::string fast = "[motor]\nrs_ohm = 1.0\nld_H = 0.3e-3\nlq_H = 0.3e-3\n[saturation]\nenabled = false\n";
  const std::string one_step = error_of(fast);
  EXPECT_NE(one_step.find("0.00015 s, is shorter than two integration steps"), std::string::npos) << one_step;
  EXPECT_NE(one_step.find("raise simulation.substeps to 2"), std::string::npos) << one_step;
  EXPECT_EQ(error_of(fast + "[simulation]\nsubsteps = 2\n"), "");
  // A motor cable is in series with the winding: 0.3 mH over twice 2 ohm is 75 us, not two
  // 50 us substeps.
  const std::string cabled = error_of(
      "[motor]\nrs_ohm = 1.0\ncable_resistance_ohm = 1.0\nld_H = 0.3e-3\nlq_H = 0.3e-3\n[saturation]\nenabled = "
      "false\n[simulation]\nsubsteps = 2\n");
  EXPECT_NE(cabled.find("over twice motor.rs_ohm + motor.cable_resistance_ohm (2 ohm), 7.5e-05 s"), std::string::npos)
      << cabled;
  EXPECT_NE(cabled.find("raise simulation.substeps to 3"), std::string::npos) << cabled;
  // The saturated inductances count where saturation is on.
  const std::string saturated =
      error_of("[motor]\nrs_ohm = 1.0\n[saturation]\nenabled = true\nld_sat_H = 0.3e-3\nlq_sat_H = 0.3e-3\n");
  EXPECT_NE(saturated.find("is shorter than two integration steps"), std::string::npos) << saturated;
}

// A header of 50,000 segments made toml++ overflow the stack (SIGSEGV): refused first
// (common/toml_depth.hpp).
TEST(plant_config, ADeepKeyIsRefusedNotACrash) {
  std::string key = "x";
  for (int k = 0; k < 50000; ++k) {
    key += ".x";
  }
  EXPECT_NE(error_of("[" + key + "]\n").find("test.toml:1: a key or table header nested more than 64 levels deep"),
            std::string::npos);
}

TEST(plant_config, ANumberTooSmallForAnyMachineIsRefused) {
  for (const char* key : {"motor.rs_ohm", "motor.ld_H", "motor.lq_H", "motor.ke_V_s_per_rad", "mechanics.inertia_kg_m2",
                          "thermal.winding_capacity_J_K", "thermal.winding_to_housing_K_W", "thermal.rotor_to_ambient_K_W"}) {
    const std::string k(key);
    const std::string text = "[" + k.substr(0, k.find('.')) + "]\n" + k.substr(k.find('.') + 1) + " = 5e-324\n";
    EXPECT_NE(error_of(text).find(k + ": must be in ["), std::string::npos) << key << ": " << error_of(text);
  }
}

TEST(plant_config, ShippedProfilesParse) {
  for (const char* name : {"reference.toml", "voltage-sensed.toml", "ideal.toml"}) {
    SCOPED_TRACE(name);
    EXPECT_NO_THROW((void)load_plant_config(kProfiles / name));
  }
}

TEST(plant_config, ReferenceProfileEqualsDefaultsAndDesign) {
  const PlantConfig c = load_plant_config(kProfiles / "reference.toml");
  // DESIGN §5 reference realism profile.
  EXPECT_DOUBLE_EQ(c.inverter.pwm_frequency_Hz, 10000.0);
  EXPECT_EQ(c.current_adc.bits, 12);
  EXPECT_DOUBLE_EQ(c.current_adc.range_A, 200.0);
  EXPECT_DOUBLE_EQ(c.current_adc.noise_A, 0.2);
  EXPECT_EQ(c.encoder.bits, 14);
  EXPECT_DOUBLE_EQ(c.inverter.dc_bus_V, 650.0);
  EXPECT_DOUBLE_EQ(c.inverter.dc_ripple_fraction, 0.01);
  EXPECT_DOUBLE_EQ(c.inverter.dc_ripple_frequency_Hz, 300.0);
  EXPECT_DOUBLE_EQ(c.inverter.dead_time_s, 1.0e-6);
  EXPECT_DOUBLE_EQ(c.inverter.device_drop_V, 1.0);
  EXPECT_FALSE(c.phase_voltage_sensing.enabled);
  EXPECT_EQ(c.emf.shape, EmfShape::trapezoidal);
  EXPECT_DOUBLE_EQ(c.load.ripple_fraction, 0.02);
  // Gain errors differ per phase.
  EXPECT_NE(c.current_adc.gain_error[0], c.current_adc.gain_error[1]);
  EXPECT_NE(c.current_adc.gain_error[1], c.current_adc.gain_error[2]);

  // Table I defaults.
  const PlantConfig d;
  EXPECT_DOUBLE_EQ(d.motor.rs_ohm, 0.133);
  EXPECT_DOUBLE_EQ(d.motor.ke_V_s_per_rad, 1.19);
  EXPECT_EQ(d.motor.pole_pairs, 3);
  EXPECT_DOUBLE_EQ(d.motor.ld_H, 11e-3 / 2.0);
  EXPECT_DOUBLE_EQ(d.mechanics.inertia_kg_m2, 0.00841);
  EXPECT_DOUBLE_EQ(d.mechanics.coulomb_Nm, 0.908);

  // The file and the defaults agree on everything the file sets.
  EXPECT_EQ(c.current_adc.offset_A, d.current_adc.offset_A);
  EXPECT_EQ(c.current_adc.gain_error, d.current_adc.gain_error);
  EXPECT_EQ(c.dc_bus_adc.noise_V, d.dc_bus_adc.noise_V);
}

TEST(plant_config, VoltageSensedAndIdealProfiles) {
  const PlantConfig v = load_plant_config(kProfiles / "voltage-sensed.toml");
  EXPECT_TRUE(v.phase_voltage_sensing.enabled);
  EXPECT_EQ(v.phase_voltage_sensing.bits, 12);
  EXPECT_DOUBLE_EQ(v.phase_voltage_sensing.range_V, 400.0);
  EXPECT_TRUE(v.inverter.dead_time_enabled);

  const PlantConfig i = load_plant_config(kProfiles / "ideal.toml");
  EXPECT_EQ(i.emf.shape, EmfShape::sinusoidal);
  EXPECT_FALSE(i.current_adc.noise_enabled);
  EXPECT_FALSE(i.inverter.dead_time_enabled);
  EXPECT_FALSE(i.inverter.device_drop_enabled);
}

TEST(plant_config, PsiMFromKe) {
  // Ke = 1.19 V·s/rad line-to-line RMS per mechanical rad/s: the phase peak EMF per
  // electrical rad/s is 1.19·sqrt(2)/sqrt(3)/3.
  EXPECT_NEAR(psi_m_from_Ke(1.19, 3), 1.19 * std::sqrt(2.0) / std::sqrt(3.0) / 3.0, 1e-12);
  // Torque constant in A RMS: 1.5·p·psi_m·sqrt(2) ≈ Kt = 2.08 Nm/A within 1 %.
  EXPECT_NEAR(1.5 * 3.0 * psi_m_from_Ke(1.19, 3) * std::sqrt(2.0), 2.08, 0.021);
}

TEST(plant_config, MissingKeysTakeDefaults) {
  const PlantConfig c = parse_plant_config("[motor]\nld_H = 0.004\n", "t.toml");
  EXPECT_DOUBLE_EQ(c.motor.ld_H, 0.004);
  EXPECT_DOUBLE_EQ(c.motor.lq_H, PlantConfig{}.motor.lq_H);
  EXPECT_EQ(c.encoder.bits, 14);
  // Integers are accepted where a number is expected.
  EXPECT_DOUBLE_EQ(parse_plant_config("[inverter]\ndc_bus_V = 600\n", "t").inverter.dc_bus_V,
                   600.0);
}

TEST(plant_config, TimeTablesFromToml) {
  const PlantConfig steps = parse_plant_config(
      "[load]\nprofile = \"steps\"\ntorque_Nm = 1.0\nsteps = [[0.5, 10.0], [1.0, -2]]\n", "t");
  EXPECT_EQ(steps.load.profile, LoadProfile::torque_steps);
  ASSERT_EQ(steps.load.points.size(), 2U);
  EXPECT_DOUBLE_EQ(steps.load.points[1].value, -2.0);

  const PlantConfig speed = parse_plant_config(
      "[load]\nprofile = \"speed\"\nspeed_points = [[0, 0], [1, 300]]\ndyno_bandwidth_Hz = 20\n",
      "t");
  EXPECT_EQ(speed.load.profile, LoadProfile::speed_cycle);
  ASSERT_EQ(speed.load.points.size(), 2U);
  EXPECT_DOUBLE_EQ(speed.load.points[1].value, 300.0);
  EXPECT_DOUBLE_EQ(speed.load.dyno_bandwidth_Hz, 20.0);

  const std::string bad = error_of("[load]\nprofile = \"speed\"\nspeed_points = [[0, 0], [1]]\n");
  EXPECT_NE(bad.find("load.speed_points"), std::string::npos) << bad;
}

TEST(plant_config, OutOfRangeNamesKeyAndRange) {
  const std::string e = error_of("[motor]\nld_H = -1\n");
  EXPECT_NE(e.find("motor.ld_H"), std::string::npos) << e;
  EXPECT_NE(e.find("must be"), std::string::npos) << e;
  EXPECT_NE(e.find("[1e-09, 1]"), std::string::npos) << e;
  EXPECT_NE(e.find("-1"), std::string::npos) << e;
  EXPECT_NE(e.find("test.toml:2"), std::string::npos) << e;  // file and line
  // Finite but beyond any machine: the motor's keys take the drive's ranges, an angle a
  // thousand radians (1e300 rad left the shaft's angle without a digit to turn by).
  EXPECT_EQ(error_of("[motor]\nld_H = 1e300\n"), "test.toml:2: motor.ld_H: must be in [1e-09, 1], got 1e+300");
  EXPECT_EQ(error_of("[motor]\nrs_ohm = 101\n"), "test.toml:2: motor.rs_ohm: must be in [1e-06, 100], got 101");
  EXPECT_EQ(error_of("[mechanics]\ninitial_angle_rad = 1e300\n"),
            "test.toml:2: mechanics.initial_angle_rad: must be in [-1000, 1000], got 1e+300");
  EXPECT_EQ(error_of("[mechanics]\ninitial_angle_rad = -7.5\n"), "");

  const std::string bits = error_of("[encoder]\nbits = 17\n");
  EXPECT_NE(bits.find("encoder.bits"), std::string::npos) << bits;
  EXPECT_NE(bits.find("[1, 16]"), std::string::npos) << bits;

  const std::string arr = error_of("[current_adc]\ngain_error = [0.0, 0.9, 0.0]\n");
  EXPECT_NE(arr.find("current_adc.gain_error"), std::string::npos) << arr;
}

TEST(plant_config, WrongTypeNamesKey) {
  const std::string e = error_of("[motor]\nld_H = \"five\"\n");
  EXPECT_NE(e.find("motor.ld_H"), std::string::npos) << e;
  EXPECT_NE(e.find("expected a number"), std::string::npos) << e;

  const std::string b = error_of("[thermal]\nenabled = 1\n");
  EXPECT_NE(b.find("thermal.enabled"), std::string::npos) << b;

  const std::string i = error_of("[encoder]\nbits = 14.5\n");
  EXPECT_NE(i.find("encoder.bits"), std::string::npos) << i;
  EXPECT_NE(i.find("integer"), std::string::npos) << i;

  const std::string a = error_of("[current_adc]\noffset_A = [0.1, 0.2]\n");
  EXPECT_NE(a.find("current_adc.offset_A"), std::string::npos) << a;

  const std::string s = error_of("[emf]\nshape = \"square\"\n");
  EXPECT_NE(s.find("emf.shape"), std::string::npos) << s;
  EXPECT_NE(s.find("trapezoidal"), std::string::npos) << s;  // lists the choices
}

TEST(plant_config, UnknownKeyIsAnErrorWithSuggestion) {
  const std::string e = error_of("[motor]\nld_HH = 0.005\n");
  EXPECT_NE(e.find("motor.ld_HH"), std::string::npos) << e;
  EXPECT_NE(e.find("unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean motor.ld_H"), std::string::npos) << e;

  const std::string s = error_of("[motr]\nld_H = 0.005\n");
  EXPECT_NE(s.find("motr"), std::string::npos) << s;
  EXPECT_NE(s.find("motr: unknown key"), std::string::npos) << s;

  const std::string top = error_of("seed = 3\n");
  EXPECT_NE(top.find("seed"), std::string::npos) << top;
}

TEST(plant_config, SyntaxErrorNamesFileAndLine) {
  const std::string e = error_of("[motor]\nld_H = = 3\n");
  EXPECT_NE(e.find("test.toml:2"), std::string::npos) << e;
}

TEST(plant_config, CrossFieldRules) {
  const std::string sat = error_of("[saturation]\nenabled = true\nlq_sat_H = 0.01\n");
  EXPECT_NE(sat.find("saturation.lq_sat_H"), std::string::npos) << sat;

  const std::string brk = error_of("[mechanics]\nbreakaway_Nm = 0.5\n");
  EXPECT_NE(brk.find("mechanics.breakaway_Nm"), std::string::npos) << brk;

  const std::string trip = error_of(
      "[emf]\nshape = \"custom\"\nharmonic_orders = [5, 9]\nharmonic_amplitudes = [0.1, 0.1]\n");
  EXPECT_NE(trip.find("emf.harmonic_orders"), std::string::npos) << trip;
  EXPECT_NE(trip.find("9"), std::string::npos) << trip;

  const std::string twice = error_of(
      "[emf]\nshape = \"custom\"\nharmonic_orders = [5, 5]\nharmonic_amplitudes = [0.1, 0.1]\n");
  EXPECT_NE(twice.find("emf.harmonic_orders: order 5 is given twice"), std::string::npos) << twice;

  const std::string bus = error_of("[inverter]\ndc_bus_V = 1e-300\n");
  EXPECT_NE(bus.find("inverter.dc_bus_V"), std::string::npos) << bus;

  const std::string len = error_of(
      "[emf]\nshape = \"custom\"\nharmonic_orders = [5, 7]\nharmonic_amplitudes = [0.1]\n");
  EXPECT_NE(len.find("emf.harmonic_amplitudes"), std::string::npos) << len;

  const std::string unused = error_of("[load]\nsteps = [[0.0, 1.0]]\n");
  EXPECT_NE(unused.find("load.steps"), std::string::npos) << unused;

  const std::string order =
      error_of("[load]\nprofile = \"steps\"\nsteps = [[1.0, 1.0], [0.5, 2.0]]\n");
  EXPECT_NE(order.find("load.steps"), std::string::npos) << order;
  EXPECT_NE(order.find("ascending"), std::string::npos) << order;

  const std::string dead = error_of("[inverter]\ndead_time_s = 6e-5\n");
  EXPECT_NE(dead.find("inverter.dead_time_s"), std::string::npos) << dead;
}

TEST(plant_config, ValidateChecksConfigsBuiltInCode) {
  PlantConfig c;
  c.motor.lq_H = -1.0;
  try {
    validate_plant_config(c);
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("motor.lq_H"), std::string::npos) << e.what();
  }
}

class PlantConfigCsv : public ::testing::Test {
 protected:
  void write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name) << text;
  }
  test::ScratchDir scratch_{"pmsm-plant-config"};
  std::filesystem::path dir_ = scratch_.path();
};
using plant_config_csv = PlantConfigCsv;

TEST_F(plant_config_csv, TorqueAndSpeedCycles) {
  write("torque.csv", "# a drive cycle\ntime_s, torque_Nm\n0, 0\n1.0, 10\n2.0, -5\n");
  const PlantConfig t =
      parse_plant_config("[load]\nprofile = \"csv\"\ncsv_path = \"torque.csv\"\n", "t", dir_);
  EXPECT_EQ(t.load.profile, LoadProfile::torque_cycle);
  ASSERT_EQ(t.load.points.size(), 3U);
  EXPECT_DOUBLE_EQ(t.load.points[2].value, -5.0);

  write("speed.csv", "speed_rad_s,time_s\n100,0\n200,1\n");
  const PlantConfig s =
      parse_plant_config("[load]\nprofile = \"csv\"\ncsv_path = \"speed.csv\"\n", "t", dir_);
  EXPECT_EQ(s.load.profile, LoadProfile::speed_cycle);
  ASSERT_EQ(s.load.points.size(), 2U);
  EXPECT_DOUBLE_EQ(s.load.points[1].time_s, 1.0);
  EXPECT_DOUBLE_EQ(s.load.points[1].value, 200.0);

  // A spreadsheet's UTF-8 byte-order mark before the header is no part of it (the header "did
  // not name time_s" with it).
  write("bom.csv", "\xEF\xBB\xBFtime_s,torque_Nm\r\n0,0\r\n1,10\r\n");
  const PlantConfig b = parse_plant_config("[load]\nprofile = \"csv\"\ncsv_path = \"bom.csv\"\n", "t", dir_);
  ASSERT_EQ(b.load.points.size(), 2U);
  EXPECT_DOUBLE_EQ(b.load.points[1].value, 10.0);

  // load_plant_config resolves the CSV relative to the TOML file.
  write("cycle.toml", "[load]\nprofile = \"csv\"\ncsv_path = \"speed.csv\"\n");
  EXPECT_EQ(load_plant_config(dir_ / "cycle.toml").load.profile, LoadProfile::speed_cycle);
}

TEST_F(plant_config_csv, BadCsvNamesKeyAndLine) {
  write("bad.csv", "time_s,torque_Nm\n0,1\n1,abc\n");
  const std::string e =
      error_of("[load]\nprofile = \"csv\"\ncsv_path = \"bad.csv\"\n", dir_);
  // The plant file's line of the key, then the CSV's line.
  EXPECT_EQ(e.rfind("test.toml:3: load.csv_path: ", 0), 0U) << e;
  EXPECT_NE(e.find("bad.csv:3: column 2: not a number"), std::string::npos) << e;

  write("header.csv", "t,torque_Nm\n0,1\n");
  const std::string h =
      error_of("[load]\nprofile = \"csv\"\ncsv_path = \"header.csv\"\n", dir_);
  EXPECT_NE(h.find("time_s"), std::string::npos) << h;

  const std::string missing =
      error_of("[load]\nprofile = \"csv\"\ncsv_path = \"nope.csv\"\n", dir_);
  EXPECT_NE(missing.find("load.csv_path"), std::string::npos) << missing;

  // A value beyond the table's range, a negative time and a column named twice: each with the
  // file and line (a value out of range was reported against load.steps, which the file lacks).
  write("big.csv", "time_s,torque_Nm\n0,1\n1,20000\n");
  const std::string big = error_of("[load]\nprofile = \"csv\"\ncsv_path = \"big.csv\"\n", dir_);
  EXPECT_NE(big.find("big.csv:3: torque_Nm must be in [-10000, 10000], got 20000"), std::string::npos) << big;
  write("fast.csv", "time_s,speed_rad_s\n0,1\n1,1e9\n");
  const std::string fast = error_of("[load]\nprofile = \"csv\"\ncsv_path = \"fast.csv\"\n", dir_);
  EXPECT_NE(fast.find("fast.csv:3: speed_rad_s must be in [-2000, 2000], got 1000000000"), std::string::npos) << fast;
  write("before.csv", "time_s,torque_Nm\n-1,1\n1,2\n");
  const std::string before = error_of("[load]\nprofile = \"csv\"\ncsv_path = \"before.csv\"\n", dir_);
  EXPECT_NE(before.find("before.csv:2: time_s must be >= 0, got -1"), std::string::npos) << before;
  write("twice.csv", "time_s,torque_Nm,time_s\n0,1,0\n");
  const std::string twice = error_of("[load]\nprofile = \"csv\"\ncsv_path = \"twice.csv\"\n", dir_);
  EXPECT_NE(twice.find("twice.csv:1: column time_s appears twice in the header"), std::string::npos) << twice;
}

TEST(plant_config, DocsListEveryKey) {
  std::ifstream in(std::filesystem::path(PMSM_SOURCE_DIR) / "docs" / "plant.md");
  ASSERT_TRUE(in) << "docs/plant.md is missing";
  std::stringstream text;
  text << in.rdbuf();
  const std::string doc = text.str();
  for (const std::string& key : plant_config_keys()) {
    EXPECT_NE(doc.find("`" + key + "`"), std::string::npos) << key << " is not documented";
  }
}

}  // namespace
}  // namespace pmsm::plant
