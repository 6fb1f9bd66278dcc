// pmsm-plant's command line: --check, configuration errors that name file, line and key, bad
// options that name the flag, and a clear message when the CAN bus cannot be opened.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <string>

#include "run_process.hpp"

namespace pmsm::test {
namespace {

const std::string kPlant = PMSM_PLANT_EXE;
const std::string kProfiles = std::string(PMSM_SOURCE_DIR) + "/plant-emulator/profiles/";

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// A TOML file in /tmp, removed at the end of the test.
class TempToml {
 public:
  explicit TempToml(const std::string& text) {
    char name[] = "/tmp/plant-cli-XXXXXX.toml";
    const int fd = ::mkstemps(name, 5);
    path_ = name;
    if (fd >= 0) {
      ::close(fd);
    }
    std::ofstream(path_) << text;
  }
  ~TempToml() { std::remove(path_.c_str()); }
  TempToml(const TempToml&) = delete;
  TempToml& operator=(const TempToml&) = delete;
  [[nodiscard]] const std::string& path() const { return path_; }

 private:
  std::string path_;
};

TEST(plant_cli, CheckAcceptsEveryProfile) {
  for (const char* profile : {"reference.toml", "ideal.toml", "voltage-sensed.toml"}) {
    const ProcessResult r = run_process(kPlant + " --check --config " + kProfiles + profile);
    EXPECT_EQ(r.exit_code, 0) << profile << ": " << r.err;
    EXPECT_TRUE(contains(r.out, "OK")) << r.out;
  }
}

// The truth is published every whole number of PWM periods, at least one: --check says what
// the node will do (it printed the flag as given, 0.001 ms where the node publishes every 0.1).
TEST(plant_cli, CheckPrintsTheTruthPeriodTheNodeUses) {
  const ProcessResult r = run_process(kPlant + " --check --truth-period-ms 0.001 --config " + kProfiles + "reference.toml");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(contains(r.out, "truth every 0.1 ms, --truth-period-ms rounded to whole PWM periods")) << r.out;
  const ProcessResult whole = run_process(kPlant + " --check --truth-period-ms 20 --config " + kProfiles + "reference.toml");
  EXPECT_TRUE(contains(whole.out, "truth every 20 ms)")) << whole.out;
  // Half a period rounds as the node rounds it (0.15 ms: two periods).
  const ProcessResult half = run_process(kPlant + " --check --truth-period-ms 0.15 --config " + kProfiles + "reference.toml");
  EXPECT_TRUE(contains(half.out, "truth every 0.2 ms,")) << half.out;
}

TEST(plant_cli, CheckRejectsABadValueNamingFileLineAndKey) {
  const TempToml bad("[motor]\nld_H = -1\n");
  const ProcessResult r = run_process(kPlant + " --check --config " + bad.path());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, bad.path() + ":2: motor.ld_H")) << r.err;
}

TEST(plant_cli, ABadOptionExitsTwoNamingIt) {
  const ProcessResult r = run_process(kPlant + " --node 16 --check --config x.toml");
  EXPECT_EQ(r.exit_code, 2);  // as a bad configuration (not CLI11's own codes)
  EXPECT_TRUE(contains(r.err, "--node")) << r.err;
  EXPECT_EQ(run_process(kPlant + " --version").exit_code, 0);
  // --help and --version whose text could not be written (a full disk) are no success: 1, named.
  for (const char* flag : {" --help", " --version"}) {
    const ProcessResult full = run_process(kPlant + flag + " >/dev/full");
    EXPECT_EQ(full.exit_code, 1) << flag;
    EXPECT_TRUE(contains(full.err, "pmsm-plant: cannot write standard output (")) << flag << ": " << full.err;
  }
}

TEST(plant_cli, CheckRejectsAnUnknownKey) {
  const TempToml bad("[inverter]\npwm_frequncy_Hz = 10000.0\n");
  const ProcessResult r = run_process(kPlant + " --check --config " + bad.path());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, "pwm_frequncy_Hz")) << r.err;
}

TEST(plant_cli, AMissingConfigFileIsNamed) {
  const ProcessResult r = run_process(kPlant + " --config /nonexistent/plant.toml --iface vcan0");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, "/nonexistent/plant.toml")) << r.err;
}

TEST(plant_cli, BadOptionsNameTheFlag) {
  ProcessResult r = run_process(kPlant + " --config " + kProfiles + "reference.toml --node 16");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_TRUE(contains(r.out + r.err, "--node")) << r.out << r.err;
  r = run_process(kPlant + " --config " + kProfiles + "reference.toml --mode fast");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_TRUE(contains(r.out + r.err, "--mode")) << r.out << r.err;
  r = run_process(kPlant + " --config " + kProfiles + "reference.toml --truth-period-ms 0");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_TRUE(contains(r.out + r.err, "--truth-period-ms")) << r.out << r.err;
  // NaN passes CLI::Range (it compares false both ways); every interval flag refuses it.
  for (const char* flag : {"--truth-period-ms", "--command-timeout-ms", "--duration-s", "--resend-interval-ms"}) {
    r = run_process(kPlant + " --config " + kProfiles + "reference.toml " + flag + " nan");
    EXPECT_NE(r.exit_code, 0) << flag;
    EXPECT_TRUE(contains(r.out + r.err, std::string(flag) + ": expected a number, got 'nan'")) << r.out << r.err;
  }
}

// A flag of the other mode did nothing and passed --check: refused, naming the mode it is for.
TEST(plant_cli, AFlagOfTheOtherModeIsRefused) {
  for (const std::string args : {"--mode lockstep --command-timeout-ms 10", "--rt-priority 50",
                                 "--mode realtime --resend-interval-ms 10"}) {
    const ProcessResult r = run_process(kPlant + " --config " + kProfiles + "reference.toml --check " + args);
    EXPECT_EQ(r.exit_code, 2) << args;
    EXPECT_TRUE(contains(r.err, "applies to --mode")) << args << ": " << r.err;
  }
  EXPECT_EQ(run_process(kPlant + " --config " + kProfiles + "reference.toml --check --mode realtime --rt-priority 50").exit_code,
            0);
}

// --accelerated-calibration keeps thermal.acceleration through a calibration; at 1 it did
// nothing and passed --check: refused, naming the key.
TEST(plant_cli, AcceleratedCalibrationWithoutAnAccelerationIsRefused) {
  const ProcessResult r = run_process(kPlant + " --config " + kProfiles + "reference.toml --check --accelerated-calibration");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, "--accelerated-calibration does nothing with thermal.acceleration = 1")) << r.err;
  const std::string accelerated = std::string(PMSM_SOURCE_DIR) + "/tests/hil/data/hil-plant.toml";
  EXPECT_EQ(run_process(kPlant + " --config " + accelerated + " --check --accelerated-calibration").exit_code, 0);
}

// Without CAN in the kernel (this build machine) the message says so; on a host with CAN it
// names the missing interface. Either way: exit 1, nothing else.
TEST(plant_cli, AnUnopenableBusIsAClearError) {
  const ProcessResult r = run_process(kPlant + " --config " + kProfiles + "reference.toml --iface can7");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(contains(r.err, "no such CAN interface 'can7'") || contains(r.err, "this kernel has no CAN support"))
      << r.err;
}

}  // namespace
}  // namespace pmsm::test
