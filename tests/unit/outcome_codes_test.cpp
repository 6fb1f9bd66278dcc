// The injection report on CAN carries core::PairOutcome as its Result value: the two
// numberings and names must agree, value by value.
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <string>

#include "pmsm/core/injection_scheduler.hpp"
#include "pmsm/core/supervisor.hpp"
#include "pmsm/hal/protocol.hpp"

namespace {

TEST(OutcomeCodes, PairOutcomeMatchesTheProtocolsInjectionResult) {
  const auto& labels = pmsm::hal::protocol::kInjectionResultLabels;
  ASSERT_EQ(labels.size(), static_cast<std::size_t>(pmsm::core::PairOutcome::kCount));
  for (std::size_t k = 0; k < labels.size(); ++k) {
    std::string name(pmsm::core::to_string(static_cast<pmsm::core::PairOutcome>(k)));
    std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return static_cast<char>(std::toupper(c)); });
    EXPECT_EQ(labels[k].value, static_cast<std::int64_t>(k));
    EXPECT_EQ(std::string(labels[k].label), name) << "value " << k;
  }
}

// Upper case with '-' as '_': the core's names spelled as the DBC's value labels.
std::string as_label(const char* name) {
  std::string s(name);
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return c == '-' ? '_' : static_cast<char>(std::toupper(c)); });
  return s;
}

TEST(OutcomeCodes, SupervisorFaultCodesMatchTheProtocols) {
  const auto& labels = pmsm::hal::protocol::kFaultCodeLabels;
  ASSERT_EQ(labels.size(), pmsm::core::kFaultCodeCount);
  for (std::size_t k = 0; k < labels.size(); ++k) {
    EXPECT_EQ(labels[k].value, static_cast<std::int64_t>(k));
    EXPECT_EQ(std::string(labels[k].label), as_label(pmsm::core::to_string(static_cast<pmsm::core::FaultCode>(k))))
        << "value " << k;
  }
}

TEST(OutcomeCodes, DriveStatesMatchTheProtocols) {
  const auto& labels = pmsm::hal::protocol::kDriveStateLabels;
  for (std::size_t k = 0; k < labels.size(); ++k) {
    EXPECT_EQ(labels[k].value, static_cast<std::int64_t>(k));
    EXPECT_EQ(std::string(labels[k].label), as_label(pmsm::core::to_string(static_cast<pmsm::core::DriveState>(k))))
        << "value " << k;
  }
}

}  // namespace
