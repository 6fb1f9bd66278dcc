// The simulator's truth at an estimate's own time (tools/sim/truth_history.hpp).
#include "truth_history.hpp"

#include <cmath>

#include <gtest/gtest.h>

namespace pmsm::app {
namespace {

TEST(TruthHistory, InterpolatesBetweenRecordsAndReturnsThemExactly) {
  TruthHistory h;
  // A winding cooling at 9 K/s, recorded every millisecond: Rs = 40 mOhm (1 + 3.9e-3 dT).
  for (int n = 0; n <= 1000; ++n) {
    const double t = 100.0 + 1e-3 * n;
    const double winding = 125.0 - 9.0 * (t - 100.0);
    h.record(t, 0.040 * (1.0 + 3.9e-3 * (winding - 125.0)), winding);
  }
  const TruthHistory::Point exact = h.at(100.5);
  EXPECT_NEAR(exact.winding_C, 125.0 - 4.5, 1e-9);
  const TruthHistory::Point mid = h.at(100.2005);  // half way between two records
  EXPECT_NEAR(mid.winding_C, 125.0 - 9.0 * 0.2005, 1e-9);
  EXPECT_NEAR(mid.rs_ohm, 0.040 * (1.0 - 3.9e-3 * 9.0 * 0.2005), 1e-12);
  EXPECT_NEAR(h.at(100.0).winding_C, 125.0, 1e-12);  // the first and the last record
  EXPECT_NEAR(h.at(101.0).winding_C, 116.0, 1e-9);
}

TEST(TruthHistory, TakesAnExtraRecordBetweenTheRegularOnes) {
  // The runner adds the publication's period when it falls between two millisecond records.
  TruthHistory h;
  h.record(0.000, 1.0, 10.0);
  h.record(0.001, 2.0, 20.0);
  h.record(0.0014, 6.0, 60.0);  // the extra one
  h.record(0.002, 3.0, 30.0);
  EXPECT_NEAR(h.at(0.0012).rs_ohm, 4.0, 1e-9);
  EXPECT_NEAR(h.at(0.0017).winding_C, 45.0, 1e-9);
  EXPECT_DOUBLE_EQ(h.at(0.0014).rs_ohm, 6.0);
  // A record that would go back in time (or is no time) is dropped: the order holds.
  h.record(0.0015, 99.0, 99.0);
  h.record(std::nan(""), 99.0, 99.0);
  EXPECT_NEAR(h.at(0.0017).winding_C, 45.0, 1e-9);
  EXPECT_DOUBLE_EQ(h.at(0.002).rs_ohm, 3.0);
}

TEST(TruthHistory, SaysNoValueOutsideWhatItHolds) {
  TruthHistory h;
  EXPECT_TRUE(std::isnan(h.at(0.0).rs_ohm));  // nothing recorded yet
  h.record(1.0, 0.1, 20.0);
  EXPECT_TRUE(std::isnan(h.at(0.999).rs_ohm));  // before the first record
  EXPECT_TRUE(std::isnan(h.at(1.001).winding_C));  // after the last
  EXPECT_TRUE(std::isnan(h.at(std::nan("")).rs_ohm));
  EXPECT_DOUBLE_EQ(h.at(1.0).rs_ohm, 0.1);
}

TEST(TruthHistory, KeepsTheLastRingFullWhenItWraps) {
  TruthHistory h;
  const std::size_t n = 3 * TruthHistory::kSize + 123;  // wrapped three times, part way into a fourth
  for (std::size_t k = 0; k < n; ++k) {
    const double t = 1e-3 * static_cast<double>(k);
    h.record(t, 1.0 + t, 2.0 * t);
  }
  const double last = 1e-3 * static_cast<double>(n - 1);
  const double oldest = 1e-3 * static_cast<double>(n - TruthHistory::kSize);
  EXPECT_NEAR(h.at(last).rs_ohm, 1.0 + last, 1e-12);
  EXPECT_NEAR(h.at(oldest).winding_C, 2.0 * oldest, 1e-9);
  EXPECT_NEAR(h.at(oldest + 0.0104).winding_C, 2.0 * (oldest + 0.0104), 1e-9);
  EXPECT_TRUE(std::isnan(h.at(oldest - 1e-3).rs_ohm));  // overwritten
  EXPECT_NEAR(h.at(last - 10.0).rs_ohm, 1.0 + last - 10.0, 1e-9);  // 10 s back: held
}

}  // namespace
}  // namespace pmsm::app
