// The injection report on CAN carries core::PairOutcome as its Result value: the two
// numberings and names must agree, value by value.
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <string>

#include "pmsm/core/injection_scheduler.hpp"
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

}  // namespace
