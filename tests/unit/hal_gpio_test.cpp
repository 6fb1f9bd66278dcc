#include "pmsm/hal/gpio.hpp"

#include <gtest/gtest.h>

#include <cerrno>
#include <filesystem>
#include <string>
#include <thread>

namespace pmsm::hal {
namespace {

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(Gpio, NoChipConfiguredGivesNullBackends) {
  const GpioLineConfig none{};
  auto enable = make_gate_enable_output(none);
  auto fault = make_fault_input(none);
  EXPECT_EQ(enable->backend_name(), "null");
  EXPECT_EQ(fault->backend_name(), "null");
  EXPECT_EQ(enable->describe(), "null");
  EXPECT_FALSE(enable->active());
  EXPECT_TRUE(enable->set_active(true));
  EXPECT_TRUE(enable->active());
  EXPECT_TRUE(enable->set_active(false));
  EXPECT_EQ(fault->fault_active(), std::optional<bool>{false});
}

TEST(Gpio, SimOutputCountsCallsAndTransitions) {
  SimGateEnableOutput enable;
  EXPECT_EQ(enable.backend_name(), "sim");
  EXPECT_FALSE(enable.active());
  EXPECT_TRUE(enable.set_active(true));
  EXPECT_TRUE(enable.set_active(true));
  EXPECT_TRUE(enable.set_active(false));
  EXPECT_EQ(enable.set_calls(), 3U);
  EXPECT_EQ(enable.activations(), 1U);
  EXPECT_EQ(enable.deactivations(), 1U);

  enable.fail_with(EIO);
  EXPECT_FALSE(enable.set_active(true));
  EXPECT_EQ(enable.last_error_number(), EIO);
  EXPECT_FALSE(enable.active());  // a failed set does not change the recorded level
  enable.fail_with(0);
  EXPECT_TRUE(enable.set_active(true));
  EXPECT_TRUE(enable.active());
}

TEST(Gpio, SimFaultInputIsSettableFromAnotherThread) {
  SimFaultInput fault;
  EXPECT_EQ(fault.fault_active(), std::optional<bool>{false});
  std::thread{[&] { fault.set_fault(true); }}.join();
  EXPECT_EQ(fault.fault_active(), std::optional<bool>{true});
  fault.fail_with(EIO);
  EXPECT_EQ(fault.fault_active(), std::nullopt);  // a failed read is not "no fault"
  EXPECT_EQ(fault.last_error_number(), EIO);
  EXPECT_EQ(fault.reads(), 3U);
}

void expect_missing_chip_error(const std::string& chip) {
  const GpioLineConfig config{chip, 17U, false};
  try {
    (void)make_gate_enable_output(config);
    FAIL() << "opening GPIO chip '" << chip << "' should have failed";
  } catch (const HalError& e) {
    EXPECT_TRUE(contains(e.what(), "GPIO chip '" + chip + "'")) << e.what();
    EXPECT_TRUE(contains(e.what(), "gate enable")) << e.what();
    EXPECT_TRUE(contains(e.what(), "not found")) << e.what();
    EXPECT_NE(e.error_number(), 0);
  }
  const GpioLineConfig by_name{chip, std::string{"FAULT_N"}, true};
  try {
    (void)make_fault_input(by_name);
    FAIL() << "opening GPIO chip '" << chip << "' should have failed";
  } catch (const HalError& e) {
    EXPECT_TRUE(contains(e.what(), "GPIO chip '" + chip + "'")) << e.what();
    EXPECT_TRUE(contains(e.what(), "fault input")) << e.what();
  }
}

TEST(Gpio, GpiodMissingChipIsAClearError) {
  expect_missing_chip_error("/dev/gpiochip-pmsm-does-not-exist");
  expect_missing_chip_error("pmsm-no-such-chip");
}

// This machine has no GPIO chip at all (DESIGN §8); where one exists this case does not apply.
TEST(Gpio, GpiodGpiochip0IsAClearErrorWhereThereIsNoChip) {
  if (std::filesystem::exists("/dev/gpiochip0")) {
    GTEST_SKIP() << "/dev/gpiochip0 exists on this machine";
  }
  expect_missing_chip_error("gpiochip0");
}

}  // namespace
}  // namespace pmsm::hal
