// The stored calibration: written atomically and read strictly (calibration_file.hpp), and
// the controller configuration's calibration.file (read at start-up, relative paths).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <utility>
#include <iterator>
#include <limits>
#include <sstream>
#include <string>

#include <toml++/toml.h>

#include "calibration_file.hpp"
#include "controller_config.hpp"
#include "scratch_dir.hpp"

namespace pmsm::app {
namespace {

namespace fs = std::filesystem;

class CalibrationFile : public ::testing::Test {
 protected:
  // (A test may take the write permission away: ScratchDir gives it back before it removes.)
  void write_text(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }
  static std::string read_text(const fs::path& p) {
    std::ifstream in(p);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
  }
  std::string error_of(const std::string& text) {
    const fs::path p = dir_ / "bad.toml";
    write_text(p, text);
    try {
      (void)read_calibration_file(p);
    } catch (const CalibrationFileError& e) {
      return e.what();
    }
    return "";
  }
  [[nodiscard]] std::size_t entries() const {
    std::size_t n = 0;
    for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir_)) ++n;
    return n;
  }
  pmsm::test::ScratchDir scratch_{"pmsm-calibration-test"};
  const fs::path dir_ = scratch_.path();
};

core::Calibration sample() {
  core::Calibration c;
  c.rs0_ohm = 0.1323127491;
  c.t0_C = 24.75;
  c.ke0_V_s_per_rad = 0.97105928;
  c.dead_time_band_A = 0.6812;
  c.calibrated = true;
  return c;
}

// A warm winding's thermal state, as the drive stores it.
StoredThermalState sample_state() {
  StoredThermalState s;
  s.state = {92.4, 71.25, 1.3};
  s.ambient_C = 31.5;
  s.saved_unix_s = 1795493852.25;
  return s;
}

// A stored file is read at every start: a corrupt one of 50,000 key segments made toml++
// overflow the stack and the daemon died at start-up; now it is an error like any other.
TEST_F(CalibrationFile, ADeeplyNestedFileIsAnErrorNotACrash) {
  std::string key = "x";
  for (int k = 0; k < 50000; ++k) {
    key += ".x";
  }
  EXPECT_NE(error_of("format = 1\n" + key + " = 1\n").find(":2: a key or table header nested more than 64 levels deep"),
            std::string::npos);
}

TEST_F(CalibrationFile, RoundTripKeepsTheValues) {
  const fs::path p = dir_ / "calibration.toml";
  write_calibration_file(p, sample(), "bench \"A\"\\1");
  const core::Calibration c = read_calibration_file(p);
  EXPECT_NEAR(c.rs0_ohm, sample().rs0_ohm, 1e-12);
  EXPECT_DOUBLE_EQ(c.t0_C, 24.75);
  EXPECT_NEAR(c.ke0_V_s_per_rad, sample().ke0_V_s_per_rad, 1e-12);
  EXPECT_DOUBLE_EQ(c.dead_time_band_A, sample().dead_time_band_A);
  EXPECT_TRUE(c.calibrated);
  // The file is TOML a person can read; the source survived its quotes and backslash.
  const toml::table t = toml::parse_file(p.string());
  EXPECT_EQ(t["source"].value<std::string>(), std::optional<std::string>("bench \"A\"\\1"));
  EXPECT_EQ(t["format"].value<int>(), std::optional<int>(kCalibrationFileFormat));
  EXPECT_TRUE(t["written_utc"].is_string());
}

// Ke0's standard error travels with it (the magnet estimate's error bar carries it); a file
// without it (written before, or by hand) reads as unknown, 0.
TEST_F(CalibrationFile, KeZeroKeepsItsErrorBarWhenKnown) {
  const fs::path p = dir_ / "calibration.toml";
  core::Calibration c = sample();
  c.ke0_std_V_s_per_rad = 6.9e-5;
  write_calibration_file(p, c, "test");
  EXPECT_DOUBLE_EQ(read_calibration_file(p).ke0_std_V_s_per_rad, 6.9e-5);
  write_calibration_file(p, sample(), "test");
  EXPECT_EQ(toml::parse_file(p.string()).get("ke0_std_V_s_per_rad"), nullptr) << "unknown is left out, not written as 0";
  EXPECT_EQ(read_calibration_file(p).ke0_std_V_s_per_rad, 0.0);
  c.ke0_std_V_s_per_rad = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(write_calibration_file(p, c, "test"), CalibrationFileError);
}

TEST_F(CalibrationFile, TheRotorAngleCorrectionIsKeptWhenMeasured) {
  const fs::path p = dir_ / "calibration.toml";
  core::Calibration measured = sample();
  measured.angle_correction_measured = true;
  measured.angle_correction_rad = -0.0349;
  write_calibration_file(p, measured, "test");
  const core::Calibration c = read_calibration_file(p);
  EXPECT_TRUE(c.angle_correction_measured);
  EXPECT_DOUBLE_EQ(c.angle_correction_rad, -0.0349);
  // A correction of exactly zero is a measurement too (the check found nothing to correct).
  measured.angle_correction_rad = 0.0;
  write_calibration_file(p, measured, "test");
  EXPECT_TRUE(read_calibration_file(p).angle_correction_measured);
  // Not measured: no key, and the configured offset holds.
  write_calibration_file(p, sample(), "test");
  EXPECT_FALSE(read_calibration_file(p).angle_correction_measured);
  EXPECT_EQ(toml::parse_file(p.string()).get("angle_correction_rad"), nullptr);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nangle_correction_rad = 2.0\n")
                .find("bad.toml:4: angle_correction_rad: 2 is out of range"),
            std::string::npos);
  measured.angle_correction_rad = std::nan("");
  EXPECT_THROW(write_calibration_file(dir_ / "c.toml", measured, "test"), CalibrationFileError);
}

// T0's uncertainty from the thermal model's rise (a calibration on the nameplate's Rs0 after the
// drive's own losses warmed the winding) travels with it, so a restart's band carries it; absent
// (a calibration on a soaked winding, or a file written before): none.
TEST_F(CalibrationFile, TheModelRisesShareOfT0IsKeptWhenThere) {
  const fs::path p = dir_ / "calibration.toml";
  core::Calibration warm = sample();
  warm.t0_rise_std_C = 1.35;
  write_calibration_file(p, warm, "test");
  EXPECT_DOUBLE_EQ(read_calibration_file(p).t0_rise_std_C, 1.35);
  write_calibration_file(p, sample(), "test");
  EXPECT_EQ(toml::parse_file(p.string()).get("t0_rise_std_C"), nullptr) << "none is left out, not written as 0";
  EXPECT_EQ(read_calibration_file(p).t0_rise_std_C, 0.0);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nt0_rise_std_C = -1.0\n")
                .find("t0_rise_std_C: -1 is out of range"),
            std::string::npos)
      << error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nt0_rise_std_C = -1.0\n");
  warm.t0_rise_std_C = std::nan("");
  EXPECT_THROW(write_calibration_file(dir_ / "c.toml", warm, "test"), CalibrationFileError);
}

// The bridge's voltage Rs0 was learned with travels with it, with its error bar: a restarted
// drive whose pairs cannot learn Vx (unipolar, fixed-angle under load) starts from it. Absent
// (not learned, or a file written before): the configured prior holds.
TEST_F(CalibrationFile, TheBridgeVoltageIsKeptWithItsErrorBarWhenLearned) {
  const fs::path p = dir_ / "calibration.toml";
  core::Calibration learned = sample();
  learned.vx_V = 7.508249925;
  learned.vx_std_V = 0.0242;
  write_calibration_file(p, learned, "test");
  const core::Calibration c = read_calibration_file(p);
  EXPECT_DOUBLE_EQ(c.vx_V, 7.508249925);
  EXPECT_DOUBLE_EQ(c.vx_std_V, 0.0242);
  EXPECT_EQ(c.vx_bus_V, 0.0) << "not written: the reference bus";
  // Learned on another bus: kept with it (its error bar is the one there).
  learned.vx_bus_V = 559.9947;
  write_calibration_file(p, learned, "test");
  EXPECT_DOUBLE_EQ(read_calibration_file(p).vx_bus_V, 559.9947);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nvx_bus_V = 560.0\n").find("vx_bus_V is the bus of a stored vx_V"),
            std::string::npos);
  learned.vx_bus_V = std::nan("");
  EXPECT_THROW(write_calibration_file(dir_ / "c.toml", learned, "test"), CalibrationFileError);
  learned.vx_bus_V = 0.0;
  write_calibration_file(p, sample(), "test");
  EXPECT_EQ(toml::parse_file(p.string()).get("vx_V"), nullptr) << "not learned is left out, not written as 0";
  EXPECT_EQ(read_calibration_file(p).vx_std_V, 0.0);
  // One without the other is a hand edit gone wrong: both named.
  const std::string one = error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nvx_V = 7.5\n");
  EXPECT_NE(one.find("vx_V and vx_std_V go together"), std::string::npos) << one;
  EXPECT_NE(one.find("only vx_V"), std::string::npos) << one;
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nvx_V = 7.5\nvx_std_V = 0.0\n")
                .find("bad.toml:5: vx_std_V: 0 is out of range"),
            std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nvx_V = nan\nvx_std_V = 0.02\n").find("bad.toml:4: vx_V"),
            std::string::npos);
  learned.vx_V = std::nan("");
  EXPECT_THROW(write_calibration_file(dir_ / "c.toml", learned, "test"), CalibrationFileError);
  learned.vx_V = 7.5;
  learned.vx_std_V = -1.0;
  EXPECT_THROW(write_calibration_file(dir_ / "c.toml", learned, "test"), CalibrationFileError);
}

TEST_F(CalibrationFile, ReplacesTheOldFileAndLeavesNoTemporary) {
  const fs::path p = dir_ / "calibration.toml";
  write_text(p, "old content that is not TOML [");
  write_calibration_file(p, sample(), "test");
  EXPECT_NEAR(read_calibration_file(p).rs0_ohm, sample().rs0_ohm, 1e-12);
  EXPECT_EQ(entries(), 1U);
}

TEST_F(CalibrationFile, AFailedWriteNamesThePathAndKeepsTheOldFile) {
  // The directory refuses new files (root ignores permission bits, so take a path whose
  // directory does not exist, and a target that is a non-empty directory).
  const fs::path missing = dir_ / "no-such-dir" / "calibration.toml";
  try {
    write_calibration_file(missing, sample(), "test");
    FAIL() << "no error";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find("no-such-dir"), std::string::npos) << e.what();
  }
  const fs::path occupied = dir_ / "calibration.toml";
  fs::create_directories(occupied / "inside");
  try {
    write_calibration_file(occupied, sample(), "test");
    FAIL() << "no error";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find("calibration.toml: cannot replace"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(fs::is_directory(occupied / "inside"));
  EXPECT_EQ(entries(), 1U);  // the temporary is gone
}

TEST_F(CalibrationFile, RefusesToStoreAnInvalidCalibration) {
  core::Calibration c = sample();
  c.rs0_ohm = std::nan("");
  EXPECT_THROW(write_calibration_file(dir_ / "c.toml", c, "test"), CalibrationFileError);
  EXPECT_EQ(entries(), 0U);
}

// The writer holds every key to the range the reader accepts: before, a calibration at an ambient
// near ambient_max_C (T0 up to 250 C) or of a very low-resistance winding was stored, and the
// next start refused the file as damaged.
TEST_F(CalibrationFile, WhatTheWriterStoresTheReaderAccepts) {
  struct Case {
    const char* key;
    void (*spoil)(core::Calibration&);
  };
  const Case cases[] = {
      {"t0_C", [](core::Calibration& c) { c.t0_C = 210.0; }},
      {"t0_C", [](core::Calibration& c) { c.t0_C = -60.0; }},
      {"rs0_ohm", [](core::Calibration& c) { c.rs0_ohm = 1e-7; }},
      {"ke0_V_s_per_rad", [](core::Calibration& c) { c.ke0_V_s_per_rad = -0.5; }},
      {"ke0_V_s_per_rad", [](core::Calibration& c) { c.ke0_V_s_per_rad = 150.0; }},
      {"dead_time_band_A", [](core::Calibration& c) { c.dead_time_band_A = -1.0; }},
      {"vx_V", [](core::Calibration& c) {
         c.vx_V = 60.0;
         c.vx_std_V = 0.1;
       }},
      {"vx_bus_V", [](core::Calibration& c) {
         c.vx_V = 6.0;
         c.vx_std_V = 0.1;
         c.vx_bus_V = std::nan("");
       }},
  };
  for (const Case& k : cases) {
    core::Calibration c = sample();
    k.spoil(c);
    try {
      write_calibration_file(dir_ / "c.toml", c, "test");
      ADD_FAILURE() << k.key << ": stored";
    } catch (const CalibrationFileError& e) {
      EXPECT_NE(std::string(e.what()).find(std::string(k.key) + " = "), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("the reader would refuse"), std::string::npos) << e.what();
    }
    EXPECT_EQ(entries(), 0U) << k.key;
  }
  // At the edges of the ranges both sides agree.
  core::Calibration edge = sample();
  edge.t0_C = 200.0;
  edge.ke0_V_s_per_rad = 0.0;
  edge.vx_V = -50.0;
  edge.vx_std_V = 100.0;
  edge.vx_bus_V = 10000.0;
  write_calibration_file(dir_ / "c.toml", edge, "test");
  const core::Calibration back = read_calibration_file(dir_ / "c.toml");
  EXPECT_EQ(back.t0_C, 200.0);
  EXPECT_EQ(back.vx_V, -50.0);
  EXPECT_EQ(back.vx_bus_V, 10000.0);
}

TEST_F(CalibrationFile, BadFilesAreRejectedWithFileLineAndKey) {
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = [\n").find("bad.toml:3"), std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nrs0 = 1\n").find("bad.toml:4: unknown key 'rs0'"),
            std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = -0.13\nt0_C = 25.0\n").find("bad.toml:2: rs0_ohm: -0.13 is out of range"),
            std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 900.0\n").find("t0_C: 900 is out of range"), std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = \"0.13\"\nt0_C = 25.0\n").find("rs0_ohm: expected a number"), std::string::npos);
  EXPECT_NE(error_of("format = 1\nt0_C = 25.0\n").find("rs0_ohm: missing"), std::string::npos);
  EXPECT_NE(error_of("format = 2\nrs0_ohm = 0.13\nt0_C = 25.0\n").find("format: 2 is not supported"), std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nke0_V_s_per_rad = nan\n").find("ke0_V_s_per_rad"),
            std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nke0_std_V_s_per_rad = -1e-4\n")
                .find("bad.toml:4: ke0_std_V_s_per_rad: -0.0001 is out of range"),
            std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\ndead_time_band_A = -0.5\n")
                .find("bad.toml:4: dead_time_band_A: -0.5 is out of range"),
            std::string::npos);
  EXPECT_NE(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\nwritten_utc = 5\n").find("bad.toml:4: written_utc: expected a string"),
            std::string::npos);
  // Ke0 may be absent (a calibration without EMF: standstill), and the band (a calibration
  // without the bridge sweep, or written before it existed: the configured band holds).
  EXPECT_EQ(error_of("format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\n"), "");
  try {
    (void)read_calibration_file(dir_ / "absent.toml");
    FAIL() << "no error";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find("absent.toml: no such file"), std::string::npos) << e.what();
  }
}

TEST_F(CalibrationFile, ControllerConfigLoadsTheFileRelativeToItself) {
  const fs::path config_path = dir_ / "drive.toml";
  const std::string text = "[calibration]\nfile = \"state/calibration.toml\"\nrs0_ohm = 0.140\nt0_C = 20.0\n";
  ControllerConfig c = parse_controller_config(toml::parse(text, config_path.string()), config_path.string(), {});
  EXPECT_EQ(fs::path(c.calibration_file), dir_ / "state" / "calibration.toml");
  // Not there yet (not commissioned): the keys hold.
  ControllerConfig missing = c;
  EXPECT_EQ(load_stored_calibration(missing), StoredCalibration::kMissing);
  EXPECT_EQ(missing.drive.calibration.rs0_ohm, 0.140);
  EXPECT_FALSE(missing.drive.calibration.calibrated);
  // Stored: it replaces them.
  fs::create_directories(dir_ / "state");
  write_calibration_file(c.calibration_file, sample(), "test");
  EXPECT_EQ(load_stored_calibration(c), StoredCalibration::kLoaded);
  EXPECT_NEAR(c.drive.calibration.rs0_ohm, sample().rs0_ohm, 1e-12);
  EXPECT_EQ(c.drive.calibration.t0_C, 24.75);
  EXPECT_TRUE(c.drive.calibration.calibrated);
  // Damaged: an error, not the nameplate.
  write_text(c.calibration_file, "format = 1\nrs0_ohm = 0\nt0_C = 25\n");
  EXPECT_THROW(load_stored_calibration(c), CalibrationFileError);
  // Valid as a file, but not this motor's: held to the plausibility window a configured
  // calibration.rs0_ohm is held to (Table I's 0.09-0.27 ohm here), on either side, and the
  // drive keeps what it had.
  const double rs_before = c.drive.calibration.rs0_ohm;
  for (const auto& [rs0, words] : {std::pair{"5.0", "rs0_ohm 5 ohm lies above the drive's plausibility window "
                                                    "(controller.injection.rs_max_ohm = 0.27 ohm)"},
                                   std::pair{"0.05", "rs0_ohm 0.05 ohm lies below the drive's plausibility window "
                                                     "(controller.injection.rs_min_ohm = 0.09 ohm)"}}) {
    write_text(c.calibration_file, std::string("format = 1\nrs0_ohm = ") + rs0 + "\nt0_C = 25\n");
    try {
      (void)load_stored_calibration(c);
      ADD_FAILURE() << "rs0_ohm = " << rs0 << " loaded";
    } catch (const CalibrationFileError& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(c.calibration_file), std::string::npos) << e.what();
    }
    EXPECT_EQ(c.drive.calibration.rs0_ohm, rs_before);
  }
  // The window's own ends are inside it.
  write_text(c.calibration_file, "format = 1\nrs0_ohm = 0.27\nt0_C = 25\n");
  EXPECT_EQ(load_stored_calibration(c), StoredCalibration::kLoaded);
  // Not configured.
  ControllerConfig none = default_controller_config();
  EXPECT_EQ(load_stored_calibration(none), StoredCalibration::kNotConfigured);
}


// A motor the configuration takes reloads the calibration it stored: the file's bound on
// rs0_ohm is the keys' (it was 10 ohm against motor.rs_ohm's 100: a 20 ohm motor's own file
// was refused).
TEST_F(CalibrationFile, AHighResistanceMotorReloadsItsOwnCalibration) {
  const fs::path config_path = dir_ / "drive.toml";
  ControllerConfig c = parse_controller_config(
      toml::parse("[motor]\nrs_ohm = 20.0\n[calibration]\nfile = \"cal.toml\"\n", config_path.string()),
      config_path.string(), {});
  core::Calibration stored = sample();
  stored.rs0_ohm = 20.5;
  write_calibration_file(c.calibration_file, stored, "test");
  EXPECT_EQ(load_stored_calibration(c), StoredCalibration::kLoaded);
  EXPECT_NEAR(c.drive.calibration.rs0_ohm, 20.5, 1e-12);
  write_text(c.calibration_file, "format = 1\nrs0_ohm = 101\nt0_C = 25\n");
  EXPECT_THROW((void)read_calibration_file(c.calibration_file), CalibrationFileError);
}

// A directory or a device where a stored file should be is named as one: a directory read as
// an empty file ("format: missing"), and /dev/zero was read until memory ran out at start.
TEST_F(CalibrationFile, ADirectoryOrADeviceIsNamedAsOne) {
  for (const auto& read : {+[](const fs::path& p) { (void)read_calibration_file(p); },
                           +[](const fs::path& p) { (void)read_thermal_state_file(p); }}) {
    for (const auto& [path, problem] : {std::pair<fs::path, std::string>{dir_, "is a directory"},
                                        {fs::path("/dev/zero"), "is not a regular file"}}) {
      try {
        read(path);
        ADD_FAILURE() << path << " was read";
      } catch (const CalibrationFileError& e) {
        EXPECT_EQ(std::string(e.what()), path.string() + ": " + problem);
      }
    }
  }
}

// Each file the drive writes is a file of its own: a thermal state written over the
// calibration lost the commissioning (the next start refused the file), and either written
// over the configuration would lose that. Relative paths, "..", and a symbolic link are the
// same file as written out.
TEST_F(CalibrationFile, TheFilesTheDriveWritesAreFilesOfTheirOwn) {
  const fs::path config_path = dir_ / "drive.toml";
  const auto error_of = [&](const std::string& text) -> std::string {
    try {
      (void)parse_controller_config(toml::parse(text, config_path.string()), config_path.string(), {});
    } catch (const ConfigError& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_EQ(error_of("[calibration]\nfile = \"state/cal.toml\"\n[thermal]\nstate_file = \"state/thermal.toml\"\n"), "");
  const std::string both = error_of(
      "[calibration]\nfile = \"state/cal.toml\"\n[thermal]\nstate_file = \"state/../state/cal.toml\"\n");
  EXPECT_NE(both.find("drive.toml:4: calibration.file and thermal.state_file name the same file (" +
                      (dir_ / "state" / "cal.toml").string() + ")"),
            std::string::npos)
      << both;
  fs::create_directories(dir_ / "state");
  write_text(dir_ / "state" / "cal.toml", "format = 1\nrs0_ohm = 0.13\nt0_C = 25\n");
  fs::create_symlink(dir_ / "state" / "cal.toml", dir_ / "link.toml");
  EXPECT_NE(error_of("[calibration]\nfile = \"state/cal.toml\"\n[thermal]\nstate_file = \"link.toml\"\n")
                .find("name the same file"),
            std::string::npos);
  const std::string self = error_of("[thermal]\nstate_file = \"drive.toml\"\n");
  EXPECT_NE(self.find("drive.toml:2: thermal.state_file names this configuration file itself"), std::string::npos)
      << self;
  EXPECT_NE(error_of("[calibration]\nfile = \"./drive.toml\"\n").find("calibration.file names this configuration file"),
            std::string::npos);
}

// A thermal.state_file that names a file the drive did not write (another axis's calibration, a
// log: a mistyped path) is not written over; an empty file, or its own earlier state, is
// replaced. (Before, the drive replaced whatever was there every 10 s.)
TEST_F(CalibrationFile, AThermalStateIsNotWrittenOverAFileOfAnotherKind) {
  const fs::path path = dir_ / "axis2.calibration";
  const std::string other = "# pmsm-thermal calibration; replaced atomically by the drive\nformat = 1\nrs0_ohm = 0.133\n";
  write_text(path, other);
  StoredThermalState s;
  s.state = {92.4, 71.25, 1.3};
  s.saved_unix_s = 1795493852.25;
  try {
    write_thermal_state_file(path, s);
    FAIL() << "written over another kind of file";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find("is there and is no thermal state file (it starts \"# pmsm-thermal calibrat"),
              std::string::npos)
        << e.what();
  }
  std::ifstream in(path);
  const std::string kept((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(kept, other);
  const fs::path empty = dir_ / "empty.thermal";
  write_text(empty, "");
  EXPECT_EQ(foreign_thermal_state_file(empty), "");
  write_thermal_state_file(empty, s);
  write_thermal_state_file(empty, s);  // its own state, replaced
  EXPECT_DOUBLE_EQ(read_thermal_state_file(empty).state.winding_C, 92.4);
  // Nor a FIFO (opened to look, it would block until a writer came) or a device.
  const fs::path fifo = dir_ / "state.fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_NE(foreign_thermal_state_file(fifo).find("is not a regular file"), std::string::npos);
  EXPECT_THROW(write_thermal_state_file(fifo, s), CalibrationFileError);
  EXPECT_TRUE(fs::is_fifo(fifo)) << "replaced by the rename";
  EXPECT_NE(foreign_thermal_state_file("/dev/null").find("is not a regular file"), std::string::npos);
}

// The thermal state kept across a restart: the same atomic write and strict read.
TEST_F(CalibrationFile, ThermalStateRoundTripAndBadFiles) {
  const fs::path path = dir_ / "axis1.thermal";
  const StoredThermalState s = sample_state();
  write_thermal_state_file(path, s);
  const StoredThermalState back = read_thermal_state_file(path);
  EXPECT_DOUBLE_EQ(back.state.winding_C, 92.4);
  EXPECT_DOUBLE_EQ(back.state.housing_C, 71.25);
  EXPECT_DOUBLE_EQ(back.state.winding_std_C, 1.3);
  EXPECT_DOUBLE_EQ(back.ambient_C, 31.5);
  EXPECT_DOUBLE_EQ(back.saved_unix_s, 1795493852.25);
  EXPECT_FALSE(back.state.has_loss_errors) << "none given, none stored";
  for (const fs::directory_entry& e : fs::directory_iterator(dir_)) {
    EXPECT_EQ(e.path().filename(), "axis1.thermal") << "a temporary was left";
  }
  // NaN is never stored as a plausible number.
  StoredThermalState bad = s;
  bad.state.winding_C = std::nan("");
  EXPECT_THROW(write_thermal_state_file(path, bad), CalibrationFileError);
  EXPECT_DOUBLE_EQ(read_thermal_state_file(path).state.winding_C, 92.4) << "the old file stays";
  write_text(path, "format = 1\nwinding_C = 950.0\nhousing_C = 70.0\nwinding_std_C = 1.0\nambient_C = 25.0\nsaved_unix_s = 1.0\n");
  try {
    (void)read_thermal_state_file(path);
    FAIL() << "950 C was accepted";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find(":2: winding_C"), std::string::npos) << e.what();
  }
}

// The axis that wrote a thermal state goes with it (its bus and node), so that a daemon does not
// take another axis's winding for its own; a file without it (from before) still reads, and a
// damaged record refuses the file rather than pass for this axis's.
TEST_F(CalibrationFile, AThermalStateKeepsTheAxisThatWroteIt) {
  const fs::path path = dir_ / "axis1.thermal";
  StoredThermalState s = sample_state();
  write_thermal_state_file(path, s);
  EXPECT_FALSE(read_thermal_state_file(path).axis.recorded()) << "none given, none stored";
  s.axis = {"can1", 7};
  write_thermal_state_file(path, s);
  const StoredThermalState back = read_thermal_state_file(path);
  EXPECT_EQ(back.axis.can_interface, "can1");
  EXPECT_EQ(back.axis.can_node, 7);
  EXPECT_DOUBLE_EQ(back.state.winding_C, 92.4);
  // Another axis does not write over it: the first to write keeps the file.
  StoredThermalState neighbour = s;
  neighbour.axis = {"can1", 8};
  try {
    write_thermal_state_file(path, neighbour);
    ADD_FAILURE() << "node 8 wrote over node 7's state";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find("is the thermal state of the axis on can1 node 7, not this one's (can1 node 8): "
                                         "not written over"),
              std::string::npos)
        << e.what();
  }
  EXPECT_EQ(read_thermal_state_file(path).axis.can_node, 7) << "the old file stays";
  // A name the reader would refuse (Linux allows a quote or a backslash in one) is not recorded,
  // and the state is stored all the same.
  for (const auto& [name, node] : {std::pair<std::string, int>{"can1", 16}, {"", 1}, {"a/b", 1}, {"can\"0", 1},
                                   {"sixteen-chars-xx", 1}}) {
    fs::remove(path);
    StoredThermalState odd = s;
    odd.axis = {name, node};
    write_thermal_state_file(path, odd);
    const StoredThermalState read_back = read_thermal_state_file(path);
    EXPECT_FALSE(read_back.axis.recorded()) << name << " node " << node;
    EXPECT_DOUBLE_EQ(read_back.state.winding_C, 92.4) << name;
  }
  const std::string head = "format = 1\nwinding_C = 90.0\nhousing_C = 70.0\nwinding_std_C = 1.0\nambient_C = 25.0\n"
                           "saved_unix_s = 1.0\n";
  const std::pair<std::string, std::string> damaged[] = {
      {"can_node = 1\n", "can_interface is missing"},
      {"can_interface = \"can0\"\n", "can_node is missing"},
      {"can_interface = \"can0\"\ncan_node = 16\n", ":8: can_node: 16 is out of range, expected in [0, 15]"},
      {"can_interface = \"can0\"\ncan_node = 1.5\n", ":8: can_node: expected an integer"},
      {"can_interface = 3\ncan_node = 1\n", ":7: can_interface: expected a string"},
      {"can_interface = \"can 0\"\ncan_node = 1\n", ":7: can_interface: \"can 0\" is no interface name"},
  };
  for (const auto& [tail, want] : damaged) {
    write_text(path, head + tail);
    try {
      (void)read_thermal_state_file(path);
      ADD_FAILURE() << "accepted: " << tail;
    } catch (const CalibrationFileError& e) {
      EXPECT_NE(std::string(e.what()).find(want), std::string::npos) << e.what();
    }
  }
}

// A calibration records its axis too: another axis's is named as such (the daemon refuses it at
// start), a file without the record (from before, or simulate's) is any axis's.
TEST_F(CalibrationFile, ACalibrationKeepsTheAxisThatWroteIt) {
  const fs::path path = dir_ / "axis1-calibration.toml";
  write_calibration_file(path, sample(), "axis1.toml", {"vcan0", 1});
  StoredAxis axis;
  EXPECT_DOUBLE_EQ(read_calibration_file(path, &axis).rs0_ohm, sample().rs0_ohm);
  EXPECT_EQ(axis, (StoredAxis{"vcan0", 1}));
  EXPECT_EQ(other_axis_problem(path.string(), axis, {"vcan0", 1}, "controller.calibration.file"), "");
  const std::string other = other_axis_problem(path.string(), axis, {"vcan0", 2}, "controller.calibration.file");
  EXPECT_NE(other.find("was written by the axis on vcan0 node 1, and this daemon is node 2 on vcan0 (does another axis's "
                       "configuration name the same controller.calibration.file?)"),
            std::string::npos)
      << other;
  EXPECT_NE(other_axis_problem(path.string(), axis, {"can0", 1}, "k"), "") << "the same node on another bus";
  write_calibration_file(path, sample(), "scenario.toml");
  (void)read_calibration_file(path, &axis);
  EXPECT_FALSE(axis.recorded()) << "none given, none stored";
  EXPECT_EQ(other_axis_problem(path.string(), axis, {"vcan0", 2}, "k"), "") << "not recorded: any axis's";
  ControllerConfig c;
  c.calibration_file = path.string();
  write_calibration_file(path, sample(), "axis1.toml", {"can1", 3});
  EXPECT_EQ(load_stored_calibration(c, &axis), StoredCalibration::kLoaded);
  EXPECT_EQ(axis, (StoredAxis{"can1", 3}));
  // Another axis's calibration is not written over (the file, unrecorded, was any axis's).
  EXPECT_THROW(write_calibration_file(path, sample(), "axis2.toml", {"can1", 4}), CalibrationFileError);
  (void)read_calibration_file(path, &axis);
  EXPECT_EQ(axis, (StoredAxis{"can1", 3})) << "the old file stays";
}

// The thermal state's writer keeps to the reader's ranges: a winding of 450 C (a filter gone
// wrong) stored would refuse the next start its warm restart. The old file stays.
TEST_F(CalibrationFile, WhatTheThermalStateWriterStoresTheReaderAccepts) {
  const fs::path path = dir_ / "axis1.thermal";
  const StoredThermalState good = sample_state();
  write_thermal_state_file(path, good);
  struct Case {
    const char* key;
    void (*spoil)(StoredThermalState&);
  };
  const Case cases[] = {
      {"winding_C", [](StoredThermalState& s) { s.state.winding_C = 450.0; }},
      {"winding_C", [](StoredThermalState& s) { s.state.winding_C = -75.0; }},
      {"housing_C", [](StoredThermalState& s) { s.state.housing_C = 401.0; }},
      {"winding_std_C", [](StoredThermalState& s) { s.state.winding_std_C = -0.1; }},
      {"winding_std_C", [](StoredThermalState& s) { s.state.winding_std_C = 2000.0; }},
      {"ambient_C", [](StoredThermalState& s) { s.ambient_C = 250.0; }},
      {"saved_unix_s", [](StoredThermalState& s) { s.saved_unix_s = -1.0; }},
  };
  for (const Case& k : cases) {
    StoredThermalState s = good;
    k.spoil(s);
    try {
      write_thermal_state_file(path, s);
      ADD_FAILURE() << k.key << ": stored";
    } catch (const CalibrationFileError& e) {
      EXPECT_NE(std::string(e.what()).find(std::string(k.key) + " = "), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("the reader would refuse"), std::string::npos) << e.what();
    }
    EXPECT_DOUBLE_EQ(read_thermal_state_file(path).state.winding_C, 92.4) << k.key << ": the old file stays";
  }
  // At the edges both sides agree.
  StoredThermalState edge = good;
  edge.state.winding_C = 400.0;
  edge.state.housing_C = -60.0;
  edge.state.winding_std_C = 0.0;
  edge.ambient_C = 200.0;
  write_thermal_state_file(path, edge);
  EXPECT_DOUBLE_EQ(read_thermal_state_file(path).state.winding_C, 400.0);
}

// The loss model's learned errors go with the thermal state: all five keys or none, with the
// node its missing loss enters (the housing; a block learned with it on the winding is refused).
TEST_F(CalibrationFile, ThermalStateKeepsTheLossModelsErrors) {
  const fs::path path = dir_ / "axis1.thermal";
  StoredThermalState s;
  s.state = {92.4, 71.25, 1.3, true, 4.25, 21.5, 0.125, 0.0625, -0.75};
  s.saved_unix_s = 1795493852.25;
  write_thermal_state_file(path, s);
  const StoredThermalState back = read_thermal_state_file(path);
  ASSERT_TRUE(back.state.has_loss_errors);
  EXPECT_DOUBLE_EQ(back.state.missing_loss_W, 4.25);
  EXPECT_DOUBLE_EQ(back.state.missing_loss_std_W, 21.5);
  EXPECT_DOUBLE_EQ(back.state.loss_scale_error, 0.125);
  EXPECT_DOUBLE_EQ(back.state.loss_scale_std, 0.0625);
  EXPECT_DOUBLE_EQ(back.state.loss_correlation, -0.75);
  EXPECT_TRUE(back.loss_errors_ignored.empty());
  // The writer never stores what the reader would refuse: out of range, the block is left out.
  StoredThermalState odd = s;
  odd.state.loss_scale_std = 50.0;
  write_thermal_state_file(path, odd);
  EXPECT_FALSE(read_thermal_state_file(path).state.has_loss_errors);
  // A bad block costs only itself: the temperatures are kept, and the reason is given.
  const std::string head = "# pmsm-thermal thermal state\nformat = 1\nwinding_C = 90.0\nhousing_C = 70.0\n"
                           "winding_std_C = 1.0\nambient_C = 25.0\nsaved_unix_s = 1.0\n";
  const std::pair<std::string, std::string> refused[] = {
      {"missing_loss_W = 3.0\nloss_scale_error = 0.1\nloss_scale_std = 0.05\nloss_correlation = 0.0\n",
       "missing_loss_std_W is missing"},
      {"missing_loss_W = 3.0\nmissing_loss_std_W = 2.0\nloss_scale_error = 7.5\nloss_scale_std = 0.05\n"
       "loss_correlation = 0.0\n",
       ":10: loss_scale_error"},  // a copper loss 8.5 times the model's
      // A file from before dP moved to the housing: its dP was the winding's.
      {"missing_loss_W = 3.0\nmissing_loss_std_W = 2.0\nloss_scale_error = 0.1\nloss_scale_std = 0.05\n"
       "loss_correlation = 0.0\n",
       "missing_loss_node is absent where this build's filter has \"housing\": its missing loss was learned on the winding"},
      {"missing_loss_node = \"winding\"\nmissing_loss_W = 3.0\nmissing_loss_std_W = 2.0\nloss_scale_error = 0.1\n"
       "loss_scale_std = 0.05\nloss_correlation = 0.0\n",
       "missing_loss_node is \"winding\""}};
  for (const auto& [tail, named] : refused) {
    write_text(path, head + tail);
    const StoredThermalState r = read_thermal_state_file(path);
    EXPECT_DOUBLE_EQ(r.state.winding_C, 90.0);
    EXPECT_FALSE(r.state.has_loss_errors);
    EXPECT_NE(r.loss_errors_ignored.find(named), std::string::npos) << r.loss_errors_ignored;
  }
}

// The cooling path's learned error goes with the thermal state as a pair of its own (both or
// neither); a bad pair costs only itself and says why.
TEST_F(CalibrationFile, ThermalStateKeepsTheCoolingPathsError) {
  const fs::path path = dir_ / "axis1.thermal";
  StoredThermalState s;
  s.state = {92.4, 71.25, 1.3, true, 4.25, 21.5, 0.125, 0.0625, -0.75, true, 0.375, 0.09375};
  s.saved_unix_s = 1795493852.25;
  write_thermal_state_file(path, s);
  const StoredThermalState back = read_thermal_state_file(path);
  ASSERT_TRUE(back.state.has_cooling_error);
  EXPECT_DOUBLE_EQ(back.state.cooling_scale_error, 0.375);
  EXPECT_DOUBLE_EQ(back.state.cooling_scale_std, 0.09375);
  EXPECT_TRUE(back.state.has_loss_errors) << "the loss errors' block is its own";
  EXPECT_TRUE(back.cooling_error_ignored.empty());
  // Not learned: not written, and read back as absent.
  StoredThermalState without = s;
  without.state.has_cooling_error = false;
  write_thermal_state_file(path, without);
  EXPECT_FALSE(read_thermal_state_file(path).state.has_cooling_error);
  EXPECT_TRUE(read_thermal_state_file(path).cooling_error_ignored.empty());
  // The writer keeps to the reader's range: a g of -0.75 (a path a quarter of the model's) is left out.
  StoredThermalState odd = s;
  odd.state.cooling_scale_error = -0.75;
  write_thermal_state_file(path, odd);
  EXPECT_FALSE(read_thermal_state_file(path).state.has_cooling_error);
  const std::string head = "# pmsm-thermal thermal state\nformat = 1\nwinding_C = 90.0\nhousing_C = 70.0\n"
                           "winding_std_C = 1.0\nambient_C = 25.0\nsaved_unix_s = 1.0\n";
  const std::pair<std::string, std::string> refused[] = {
      {"cooling_scale_error = 0.2\n", "cooling_scale_std is missing"},
      {"cooling_scale_std = 0.1\n", "cooling_scale_error is missing"},
      {"cooling_scale_error = 1.5\ncooling_scale_std = 0.1\n", ":8: cooling_scale_error"},
      {"cooling_scale_error = 0.2\ncooling_scale_std = nan\n", ":9: cooling_scale_std"}};
  for (const auto& [tail, named] : refused) {
    write_text(path, head + tail);
    const StoredThermalState r = read_thermal_state_file(path);
    EXPECT_DOUBLE_EQ(r.state.winding_C, 90.0);
    EXPECT_FALSE(r.state.has_cooling_error);
    EXPECT_NE(r.cooling_error_ignored.find(named), std::string::npos) << r.cooling_error_ignored;
  }
}

// Only what the drive wrote is taken: a file without its header (written by hand, or another
// file that happens to parse) is refused with the reason, as the writer refuses to replace it;
// taken, it would be restored at every start and never written over.
TEST_F(CalibrationFile, AThermalStateWithoutTheDrivesHeaderIsNotUsed) {
  const fs::path path = dir_ / "axis1.thermal";
  const std::string body =
      "format = 1\nwinding_C = 92.5\nhousing_C = 70.0\nwinding_std_C = 1.0\nambient_C = 25.0\nsaved_unix_s = 1.0\n";
  write_text(path, "# pmsm-thermal thermal state\n" + body);
  EXPECT_DOUBLE_EQ(read_thermal_state_file(path).state.winding_C, 92.5) << "the premise: with the header it reads";
  write_text(path, body);
  try {
    (void)read_thermal_state_file(path);
    FAIL() << "a file without the header was taken";
  } catch (const CalibrationFileError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("is no thermal state file (it starts \"format = 1\""), std::string::npos) << what;
    EXPECT_NE(what.find(": not used"), std::string::npos) << what;
  }
  EXPECT_NE(foreign_thermal_state_file(path).find("not written over"), std::string::npos);
}

// Killed at any point of a write (SIGKILL: no destructor, no handler runs), the writer leaves
// the old file or the new one, never a torn, empty or missing one; the next write removes the
// temporary a killed writer left behind. 100 kills at random points of a child that writes
// the calibration and the thermal state in a loop, each value one step past the last. In
// /dev/shm where there is one (fsync is free there, so the kills land anywhere in a write,
// not mostly inside fsync).
TEST_F(CalibrationFile, SigkillDuringWritesLeavesTheOldOrTheNewFile) {
  fs::path dir = dir_;
  if (fs::is_directory("/dev/shm")) {
    dir = fs::path("/dev/shm") / dir_.filename();
    fs::remove_all(dir);
    fs::create_directories(dir);
  }
  struct RemoveAtEnd {
    fs::path path;
    ~RemoveAtEnd() {
      std::error_code ec;
      fs::remove_all(path, ec);
    }
  } remove_at_end{dir};
  const fs::path calibration = dir / "calibration.toml";
  const fs::path thermal = dir / "axis1.thermal";
  constexpr double kStep = 1e-6;
  auto calibration_of = [&](long k) {
    core::Calibration c = sample();
    c.rs0_ohm = 0.1 + kStep * static_cast<double>(k);
    return c;
  };
  auto thermal_of = [](long k) {
    StoredThermalState s;
    s.state = {30.0 + 1e-4 * static_cast<double>(k), 30.0, 1.0};
    s.ambient_C = 25.0;
    s.saved_unix_s = 1795493852.0 + static_cast<double>(k);
    return s;
  };
  long k = 0;       // the last value written to the calibration (it is written first)
  long k_thermal = 0;
  write_calibration_file(calibration, calibration_of(k), "kill test");
  write_thermal_state_file(thermal, thermal_of(k));
  std::srand(20261124U);
  int killed_mid_loop = 0;
  for (int round = 0; round < 100; ++round) {
    const long start = k + 1;
    const pid_t child = ::fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      try {
        for (long j = start;; ++j) {
          write_calibration_file(calibration, calibration_of(j), "kill test");
          write_thermal_state_file(thermal, thermal_of(j));
        }
      } catch (...) {
        ::_exit(3);  // never back into the test runner from the child
      }
    }
    // Until the child has written once (the files are atomic: reading them meanwhile is
    // safe), then 0-2 ms: anywhere in a later write.
    for (int wait = 0; wait < 5000; ++wait) {
      if (std::lround((read_calibration_file(calibration).rs0_ohm - 0.1) / kStep) >= start) {
        break;
      }
      ::usleep(100);
    }
    ::usleep(static_cast<useconds_t>(std::rand() % 2000));
    ASSERT_EQ(::kill(child, SIGKILL), 0);
    int status = 0;
    ASSERT_EQ(::waitpid(child, &status, 0), child);
    killed_mid_loop += WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL ? 1 : 0;

    // Both files parse, and each holds a value the writer wrote, no older than before.
    const double rs0 = read_calibration_file(calibration).rs0_ohm;
    const double steps = (rs0 - 0.1) / kStep;
    const long kc = std::lround(steps);
    ASSERT_NEAR(steps, static_cast<double>(kc), 1e-3) << "round " << round << ": rs0 " << rs0 << " was never written";
    ASSERT_GE(kc, k) << "round " << round << ": the calibration went back";
    const StoredThermalState t = read_thermal_state_file(thermal);
    const long kt = std::lround(t.saved_unix_s - 1795493852.0);
    ASSERT_NEAR(t.state.winding_C, 30.0 + 1e-4 * static_cast<double>(kt), 1e-9) << "round " << round;
    ASSERT_GE(kt, k_thermal) << "round " << round << ": the thermal state went back";
    ASSERT_LE(kt, kc) << "round " << round << ": the loop writes the calibration first";
    k = kc;
    k_thermal = kt;
  }
  EXPECT_EQ(killed_mid_loop, 100) << "a child ended otherwise (exit 3: a write failed)";
  EXPECT_GE(k, 100) << "every round waited for a write";
  // A killed writer's temporaries (".NAME.tmp.PID") are gone after the next write.
  write_calibration_file(calibration, calibration_of(k + 1), "after the kills");
  write_thermal_state_file(thermal, thermal_of(k + 1));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2);
}

// A calibration's Rs0 far above the configured nameplate names a motor cable as the likely
// cause: round 8's agitator, 0.320 ohm of winding and 0.0759 of cable at 35 C, configured with
// the nameplate's 0.33 at 25 C. Once the cable is configured, nothing; a cable configured too
// small is named as such.
TEST(CalibrationWarning, AnRs0FarAboveTheNameplateNamesACable) {
  core::DriveConfig d;
  d.motor.rs_ohm = 0.33;
  d.motor.rs_reference_temp_C = 25.0;
  core::Calibration c;
  c.rs0_ohm = 0.320 * (234.5 + 35.0) / (234.5 + 25.0) + 0.0759;
  c.t0_C = 35.0;
  const std::string w = rs0_off_nameplate_warning(d, c);
  EXPECT_NE(w.find("calibration: Rs0 0.40823 ohm is +19 % off motor.rs_ohm referred to 35.0 C (0.34272 ohm)"),
            std::string::npos)
      << w;
  EXPECT_NE(w.find("A motor cable the configuration does not give (motor.cable_resistance_ohm)"), std::string::npos) << w;
  d.thermal.cable_resistance_20C_ohm = 0.0717;
  EXPECT_EQ(rs0_off_nameplate_warning(d, c), "");
  d.thermal.cable_resistance_20C_ohm = 0.005;
  EXPECT_NE(rs0_off_nameplate_warning(d, c).find("More cable than motor.cable_resistance_ohm gives"), std::string::npos);
  // Within 10 % of it (a nameplate's tolerance), nothing.
  d.thermal.cable_resistance_20C_ohm = 0.0;
  c.rs0_ohm = 0.33 * (234.5 + 35.0) / (234.5 + 25.0) * 1.09;
  EXPECT_EQ(rs0_off_nameplate_warning(d, c), "");
  // Far below it: the nameplate is checked.
  c.rs0_ohm = 0.25;
  EXPECT_NE(rs0_off_nameplate_warning(d, c).find("Check motor.rs_ohm"), std::string::npos);
}

// A Ke0 far off the motor's EMF constant (a calibration of this drive measuring a
// motor.ke_V_s_per_rad entered 40 % low, another motor's file, a Ke0 per electrical rad/s) is
// warned of with both figures; within 30 % (a magnet's temperature, a data sheet), or without a
// Ke0, nothing. (Refused at load, the drive's own measurement was a file its next start refused.)
TEST(CalibrationWarning, AKe0FarOffTheMotorsEmfConstantIsNamed) {
  core::DriveConfig d;
  const double motor_ke = core::emf_constant_dq_V_s_per_rad(d.motor);
  core::Calibration c;
  EXPECT_EQ(ke0_off_motor_warning(d, c), "") << "no Ke0";
  c.ke0_V_s_per_rad = 1.29 * motor_ke;
  EXPECT_EQ(ke0_off_motor_warning(d, c), "");
  c.ke0_V_s_per_rad = 0.71 * motor_ke;
  EXPECT_EQ(ke0_off_motor_warning(d, c), "");
  c.ke0_V_s_per_rad = motor_ke / 0.6;
  const std::string w = ke0_off_motor_warning(d, c);
  EXPECT_NE(w.find("is +67 % off motor.ke_V_s_per_rad's"), std::string::npos) << w;
  EXPECT_NE(w.find("motor.ke_V_s_per_rad is wrong"), std::string::npos) << w;
  c.ke0_V_s_per_rad = motor_ke / d.motor.pole_pairs;
  EXPECT_NE(ke0_off_motor_warning(d, c).find("% off"), std::string::npos) << "per electrical rad/s";
}

// A stored calibration whose Rs0 the configured cable takes whole is refused with both named.
TEST(CalibrationWarning, AStoredRs0ACableTakesWholeIsRefused) {
  const pmsm::test::ScratchDir scratch{"pmsm-cable"};
  const fs::path& dir = scratch.path();
  ControllerConfig config = default_controller_config();
  config.calibration_file = (dir / "calibration.toml").string();
  core::Calibration stored;
  stored.rs0_ohm = 0.095;
  stored.t0_C = 20.0;
  stored.calibrated = true;
  write_calibration_file(config.calibration_file, stored, "test");
  config.drive.thermal.cable_resistance_20C_ohm = 0.1;
  try {
    (void)load_stored_calibration(config);
    ADD_FAILURE() << "a calibration the cable takes whole was loaded";
  } catch (const CalibrationFileError& e) {
    EXPECT_NE(std::string(e.what()).find("controller.motor.cable_resistance_ohm (0.1 ohm at 20 C) is 0.1 ohm at 20 C, not "
                                         "below the calibration's Rs0 (0.095 ohm)"),
              std::string::npos)
        << e.what();
  }
  config.drive.thermal.cable_resistance_20C_ohm = 0.02;
  EXPECT_EQ(load_stored_calibration(config), StoredCalibration::kLoaded);
}

}  // namespace
}  // namespace pmsm::app
