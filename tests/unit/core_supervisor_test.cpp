// The supervisor: every transition of the drive state machine, every fault with its own code,
// latched until a clear request finds the cause gone, counted once per latching, and the
// safe output (power stage off) asserted in every faulted case.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "pmsm/core/drive_controller.hpp"
#include "pmsm/core/supervisor.hpp"

namespace pmsm::core {
namespace {

constexpr double kPeriod = 1e-4;
constexpr double kNan = std::numeric_limits<double>::quiet_NaN();

SupervisorConfig config() {
  SupervisorConfig c;
  c.dc_bus_min_V = 400.0;
  c.dc_bus_max_V = 800.0;
  c.overcurrent_A = 180.0;
  c.current_sum_max_A = 20.0;
  c.max_speed_rad_s = 1000.0;  // 0.1 rad per period: about 260 counts of 16384, x1.5 + 2
  c.overspeed_rad_s = 0.0;     // off, but in its own test: the encoder's tests turn near 1000
  c.encoder_counts = 16384;
  c.sensor_timeout_periods = 5;
  c.sensor_recovery_periods = 3;
  c.command_timeout_s = 0.1;
  c.trip_temp_C = 180.0;
  c.trip_hysteresis_C = 10.0;
  return c;
}

SupervisedSample healthy() {
  SupervisedSample s;
  s.i_A = {10.0, -5.0, -5.0};
  s.vdc_V = 650.0;
  s.encoder_count = 1000;
  return s;
}

SupervisorInput running(const SupervisedSample& s = healthy()) {
  SupervisorInput in;
  in.sample = s;
  in.frontend_ready = true;
  in.enable_requested = true;
  return in;
}

std::uint32_t count(const Supervisor& sup, FaultCode code) { return sup.counts()[static_cast<std::size_t>(code)]; }

TEST(Supervisor, StartsInInitThenStandbyThenRunningAndBack) {
  Supervisor sup(config(), kPeriod);
  SupervisorInput in = running();
  in.frontend_ready = false;
  EXPECT_EQ(sup.step(in).state, DriveState::kInit);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  in.frontend_ready = true;
  in.enable_requested = false;
  EXPECT_EQ(sup.step(in).state, DriveState::kStandby);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  in.enable_requested = true;
  EXPECT_EQ(sup.step(in).state, DriveState::kRunning);
  EXPECT_TRUE(sup.status().power_stage_enabled);
  EXPECT_TRUE(sup.status().sample_usable);
  in.calibrating = true;
  EXPECT_EQ(sup.step(in).state, DriveState::kCalibrating);
  EXPECT_TRUE(sup.status().power_stage_enabled);
  in.calibrating = false;
  in.enable_requested = false;
  EXPECT_EQ(sup.step(in).state, DriveState::kStandby);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  EXPECT_EQ(sup.status().latched_mask, 0U);
}

// One implausible sample: fault latched with its own code, gates off in the same period,
// counted once, kept while the cause persists, cleared only by a request once it is gone.
struct SampleFaultCase {
  const char* name;
  FaultCode code;
  SupervisedSample bad;
  double measured = 0.0;  // what the fault's cause measured (Supervisor::latched_values; the log)
};

SupervisedSample with_currents(double a, double b, double c) {
  SupervisedSample s = healthy();
  s.i_A = {a, b, c};
  return s;
}
SupervisedSample with_vdc(double v) {
  SupervisedSample s = healthy();
  s.vdc_V = v;
  return s;
}
SupervisedSample with_encoder(std::uint32_t count) {
  SupervisedSample s = healthy();
  s.encoder_count = count;
  return s;
}
SupervisedSample with_ambient(double celsius) {
  SupervisedSample s = healthy();
  s.ambient_C = celsius;
  return s;
}
SupervisedSample with_hardware_overcurrent() {
  SupervisedSample s = healthy();
  s.hardware_overcurrent = true;
  return s;
}

class SampleFault : public ::testing::TestWithParam<SampleFaultCase> {};

TEST_P(SampleFault, LatchesGatesOffCountsOnceAndClearsOnlyWhenGone) {
  const SampleFaultCase& c = GetParam();
  Supervisor sup(config(), kPeriod);
  ASSERT_TRUE(sup.step(running()).power_stage_enabled);

  const SupervisorStatus& s = sup.step(running(c.bad));
  EXPECT_EQ(s.state, DriveState::kFault);
  EXPECT_FALSE(s.power_stage_enabled) << "gates off in the period of the bad sample";
  EXPECT_FALSE(s.sample_usable) << "the controller must not see it";
  EXPECT_TRUE(sup.latched(c.code));
  EXPECT_EQ(s.first_fault, c.code);
  EXPECT_EQ(count(sup, c.code), 1U);
  EXPECT_DOUBLE_EQ(sup.latched_values()[static_cast<std::size_t>(c.code)], c.measured);

  // The cause persists: still latched, counted once, a clear request does nothing. (A jump
  // is an event between two samples: the same angle again is no jump.)
  if (c.code != FaultCode::kEncoderJump) {
    sup.request_clear();
    sup.step(running(c.bad));
    EXPECT_TRUE(sup.latched(c.code));
    EXPECT_EQ(count(sup, c.code), 1U);
    EXPECT_FALSE(sup.status().power_stage_enabled);
  }

  // The cause is gone: still latched (faults do not clear themselves) ...
  for (int k = 0; k < 5; ++k) {
    sup.step(running());
  }
  EXPECT_TRUE(sup.latched(c.code));
  EXPECT_EQ(sup.status().state, DriveState::kFault);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  // ... until a clear request.
  sup.request_clear();
  EXPECT_EQ(sup.step(running()).state, DriveState::kRunning);
  EXPECT_TRUE(sup.status().power_stage_enabled);
  EXPECT_EQ(sup.status().latched_mask, 0U);
  EXPECT_EQ(sup.status().first_fault, FaultCode::kNone);
  EXPECT_EQ(count(sup, c.code), 1U);
}

INSTANTIATE_TEST_SUITE_P(
    EveryInput, SampleFault,
    ::testing::Values(
        SampleFaultCase{"NanCurrent", FaultCode::kInputNotFinite, with_currents(kNan, 0.0, 0.0)},
        SampleFaultCase{"InfiniteCurrent", FaultCode::kInputNotFinite,
                        with_currents(std::numeric_limits<double>::infinity(), 0.0, 0.0)},
        SampleFaultCase{"NanDcBus", FaultCode::kInputNotFinite, with_vdc(kNan)},
        SampleFaultCase{"ZeroDcBus", FaultCode::kDcBusUndervoltage, with_vdc(0.0), 0.0},
        SampleFaultCase{"LowDcBus", FaultCode::kDcBusUndervoltage, with_vdc(399.0), 399.0},
        SampleFaultCase{"HighDcBus", FaultCode::kDcBusOvervoltage, with_vdc(801.0), 801.0},
        SampleFaultCase{"Overcurrent", FaultCode::kOvercurrent, with_currents(181.0, -90.5, -90.5), 181.0},
        SampleFaultCase{"NegativeOvercurrent", FaultCode::kOvercurrent, with_currents(-90.5, -90.5, 181.0), 181.0},
        SampleFaultCase{"CurrentSum", FaultCode::kCurrentSum, with_currents(30.0, 0.0, 0.0), 30.0},
        SampleFaultCase{"EncoderJump", FaultCode::kEncoderJump, with_encoder(1000 + 500), 500.0},
        SampleFaultCase{"EncoderOutOfRange", FaultCode::kEncoderJump, with_encoder(16384), 16384.0},
        SampleFaultCase{"HardwareOvercurrent", FaultCode::kHardwareOvercurrent, with_hardware_overcurrent()},
        SampleFaultCase{"AmbientTooHot", FaultCode::kAmbientImplausible, with_ambient(327.0), 327.0},
        SampleFaultCase{"AmbientTooCold", FaultCode::kAmbientImplausible, with_ambient(-60.0), -60.0}),
    [](const ::testing::TestParamInfo<SampleFaultCase>& param_info) { return std::string(param_info.param.name); });

TEST(Supervisor, EncoderMovesFreelyWithinTheSpeedLimitAndAcrossTheWrap) {
  Supervisor sup(config(), kPeriod);
  SupervisedSample s = healthy();
  std::uint32_t count_now = 16000;
  for (int k = 0; k < 100; ++k) {
    s.encoder_count = count_now;
    ASSERT_TRUE(sup.step(running(s)).power_stage_enabled) << "period " << k;
    count_now = (count_now + 250U) % 16384U;  // 0.096 rad per period, below 0.1
  }
  EXPECT_EQ(sup.status().latched_mask, 0U);
}

TEST(Supervisor, EncoderStepAfterMissingSamplesIsAllowedProportionally) {
  Supervisor sup(config(), kPeriod);
  sup.step(running(with_encoder(1000)));
  SupervisorInput none = running();
  none.sample.reset();
  for (int k = 0; k < 3; ++k) {
    EXPECT_FALSE(sup.step(none).power_stage_enabled) << "no sample, no switching";
  }
  // Four periods at 250 counts each: within the limit for four periods.
  EXPECT_TRUE(sup.step(running(with_encoder(2000))).power_stage_enabled);
  EXPECT_EQ(sup.status().latched_mask, 0U);
}

TEST(Supervisor, SensorTimeoutAfterNPeriodsAndRecoversByItself) {
  Supervisor sup(config(), kPeriod);
  sup.step(running());
  SupervisorInput none = running();
  none.sample.reset();
  for (int k = 1; k < 5; ++k) {
    const SupervisorStatus& s = sup.step(none);
    EXPECT_FALSE(s.power_stage_enabled);
    EXPECT_NE(s.state, DriveState::kFault) << "not yet a fault after " << k << " periods";
  }
  EXPECT_EQ(sup.step(none).state, DriveState::kFault);
  EXPECT_TRUE(sup.latched(FaultCode::kSensorTimeout));
  EXPECT_EQ(count(sup, FaultCode::kSensorTimeout), 1U);
  for (int k = 0; k < 20; ++k) {
    sup.step(none);
  }
  EXPECT_EQ(count(sup, FaultCode::kSensorTimeout), 1U) << "counted once while it persists";
  // Samples return: after sensor_recovery_periods the fault clears without a request.
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault);
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault);
  EXPECT_EQ(sup.step(running()).state, DriveState::kRunning);
  EXPECT_TRUE(sup.status().power_stage_enabled);
  EXPECT_FALSE(sup.latched(FaultCode::kSensorTimeout));
}

TEST(Supervisor, TheAngleIsTakenAfreshAfterASensorLoss) {
  Supervisor sup(config(), kPeriod);
  sup.step(running(with_encoder(1000)));
  SupervisorInput none = running();
  none.sample.reset();
  for (int k = 0; k < 5; ++k) {
    sup.step(none);
  }
  ASSERT_TRUE(sup.latched(FaultCode::kSensorTimeout));
  sup.step(running(with_encoder(9000)));  // a quarter turn and more: unknown time has passed
  EXPECT_FALSE(sup.latched(FaultCode::kEncoderJump));
  sup.step(running(with_encoder(9000 + 5000)));  // but the next step is judged again
  EXPECT_TRUE(sup.latched(FaultCode::kEncoderJump));
}

// A shaft turned faster than overspeed_rad_s (an overhauling load, a runaway in torque control)
// trips the drive; the speed is the encoder's counts over a window of about 1 ms (10 periods
// here), so a count's quantization is 0.38 rad/s. The fault stays while the shaft is fast and
// clears on request once a window finds it below the limit.
TEST(Supervisor, OverspeedTripsWithinAFewWindowsAndClearsWhenSlower) {
  SupervisorConfig c = config();
  c.overspeed_rad_s = 500.0;
  Supervisor sup(c, kPeriod);
  double angle_counts = 1000.0;
  auto turn = [&](double speed_rad_s, int periods) {
    for (int k = 0; k < periods; ++k) {
      angle_counts += speed_rad_s * kPeriod / (2.0 * std::acos(-1.0)) * 16384.0;
      const double wrapped = std::fmod(angle_counts, 16384.0);
      sup.step(running(with_encoder(static_cast<std::uint32_t>(std::floor(wrapped < 0.0 ? wrapped + 16384.0 : wrapped)))));
    }
  };
  turn(495.0, 200);  // 1 % below: never
  EXPECT_FALSE(sup.latched(FaultCode::kOverspeed));
  EXPECT_EQ(sup.status().state, DriveState::kRunning);
  turn(-495.0, 200);  // either way round
  EXPECT_FALSE(sup.latched(FaultCode::kOverspeed));
  turn(-505.0, 20);  // 1 % above: within two windows
  EXPECT_TRUE(sup.latched(FaultCode::kOverspeed));
  EXPECT_EQ(sup.status().state, DriveState::kFault);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  EXPECT_FALSE(sup.latched(FaultCode::kEncoderJump)) << "a speed, not a jump";
  sup.request_clear();
  turn(-505.0, 10);
  EXPECT_TRUE(sup.latched(FaultCode::kOverspeed)) << "still too fast: the request does not clear it";
  turn(-100.0, 20);
  sup.request_clear();
  turn(-100.0, 1);
  EXPECT_FALSE(sup.latched(FaultCode::kOverspeed));
  EXPECT_EQ(count(sup, FaultCode::kOverspeed), 1U);
  // Off: a runaway is not judged.
  c.overspeed_rad_s = 0.0;
  Supervisor off(c, kPeriod);
  for (int k = 0; k < 50; ++k) {
    off.step(running(with_encoder(static_cast<std::uint32_t>(1000 + 200 * k) % 16384U)));  // 767 rad/s
  }
  EXPECT_FALSE(off.latched(FaultCode::kOverspeed));
  EXPECT_FALSE(off.latched(FaultCode::kEncoderJump));
}

// A step without a sample may stand for several periods (the daemon's sample timeout is 20 of
// them): the encoder's step after it is judged over the periods that passed, so a shaft turning
// at 90 % of the overspeed limit is neither an overspeed nor an encoder jump.
TEST(Supervisor, TheEncodersChecksCountThePeriodsAStepWithoutASampleStoodFor) {
  SupervisorConfig c = config();
  c.overspeed_rad_s = 500.0;
  Supervisor sup(c, kPeriod);
  const double counts_per_period = 450.0 * kPeriod / (2.0 * std::acos(-1.0)) * 16384.0;  // 117.4
  double angle_counts = 1000.0;
  auto sample_after = [&](int periods) {
    angle_counts += periods * counts_per_period;
    return running(with_encoder(static_cast<std::uint32_t>(std::floor(std::fmod(angle_counts, 16384.0)))));
  };
  for (int k = 0; k < 30; ++k) {
    sup.step(sample_after(1));
  }
  for (int gap = 0; gap < 3; ++gap) {
    SupervisorInput none = running();
    none.sample.reset();
    none.periods = 20;
    sup.step(none);
    sup.step(sample_after(21));
    for (int k = 0; k < 30; ++k) {
      sup.step(sample_after(1));
    }
  }
  EXPECT_FALSE(sup.latched(FaultCode::kEncoderJump));
  EXPECT_FALSE(sup.latched(FaultCode::kOverspeed));
  // The same step counted as two periods would be a jump: the check is not blind.
  SupervisorInput none = running();
  none.sample.reset();
  sup.step(none);
  sup.step(sample_after(21));
  EXPECT_TRUE(sup.latched(FaultCode::kEncoderJump));
}

TEST(Supervisor, CommandTimeoutOnlyWhileEnabledAndClearedByAFreshCommandAndARequest) {
  Supervisor sup(config(), kPeriod);
  SupervisorInput in = running();
  in.enable_requested = false;
  in.command_age_s = 5.0;
  EXPECT_EQ(sup.step(in).state, DriveState::kStandby) << "standby needs no commands";
  in.enable_requested = true;
  in.command_age_s = 0.05;
  EXPECT_EQ(sup.step(in).state, DriveState::kRunning);
  in.command_age_s = 0.11;
  EXPECT_EQ(sup.step(in).state, DriveState::kFault);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  EXPECT_TRUE(sup.latched(FaultCode::kCommandTimeout));
  sup.request_clear();
  EXPECT_EQ(sup.step(in).state, DriveState::kFault) << "still stale";
  in.command_age_s = 0.0;
  EXPECT_EQ(sup.step(in).state, DriveState::kFault) << "fresh, but not cleared";
  sup.request_clear();
  EXPECT_EQ(sup.step(in).state, DriveState::kRunning);
  in.command_age_s = kNan;
  EXPECT_EQ(sup.step(in).state, DriveState::kFault) << "an unknown age is not fresh";
}

TEST(Supervisor, OvertemperatureTripsAboveTheLimitAndClearsBelowTheHysteresis) {
  Supervisor sup(config(), kPeriod);
  SupervisorInput in = running();
  in.winding_C = 179.0;
  EXPECT_EQ(sup.step(in).state, DriveState::kRunning);
  in.winding_C = 181.0;
  EXPECT_EQ(sup.step(in).state, DriveState::kFault);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  EXPECT_TRUE(sup.latched(FaultCode::kOvertemperature));
  in.winding_C = 175.0;  // below the trip, within the hysteresis: the cause is still there
  sup.request_clear();
  EXPECT_EQ(sup.step(in).state, DriveState::kFault);
  in.winding_C = 169.0;
  sup.request_clear();
  EXPECT_EQ(sup.step(in).state, DriveState::kRunning);
  EXPECT_EQ(count(sup, FaultCode::kOvertemperature), 1U);
}

TEST(Supervisor, ReportedConditionsLatchAndBlockClearingWhilePresent) {
  Supervisor sup(config(), kPeriod);
  sup.report(FaultCode::kGpioFault, true);
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  sup.request_clear();
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault);
  sup.report(FaultCode::kGpioFault, false);
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault) << "latched until cleared";
  sup.request_clear();
  EXPECT_EQ(sup.step(running()).state, DriveState::kRunning);
}

TEST(Supervisor, AnInterfaceLossClearsItselfWhenTheInterfaceAndTheSamplesAreBack) {
  Supervisor sup(config(), kPeriod);
  sup.report(FaultCode::kInterfaceDown, true);
  SupervisorInput none = running();
  none.sample.reset();
  EXPECT_EQ(sup.step(none).state, DriveState::kFault);
  for (int k = 0; k < 5; ++k) {
    sup.step(running());  // samples, but the caller still reports the interface down
  }
  EXPECT_TRUE(sup.latched(FaultCode::kInterfaceDown));
  sup.report(FaultCode::kInterfaceDown, false);
  for (int k = 0; k < 3; ++k) {
    sup.step(running());
  }
  EXPECT_FALSE(sup.latched(FaultCode::kInterfaceDown));
  EXPECT_EQ(sup.status().state, DriveState::kRunning);
}

TEST(Supervisor, APowerStageSamplingAtAnotherPeriodIsAFaultThatHoldsWhileItLasts) {
  constexpr double kStep = 0.25e-6;  // the bus's resolution (SENSOR_SAMPLE PwmPeriod)
  Supervisor sup(config(), kPeriod);  // 100 us: code 400
  // One step either way is a match, two are not, on both sides alike.
  for (const int code : {399, 400, 401}) {
    sup.set_reported_period(code * kStep, kStep);
    EXPECT_EQ(sup.step(running()).state, DriveState::kRunning) << code;
  }
  for (const int code : {398, 402}) {
    Supervisor other(config(), kPeriod);
    other.set_reported_period(code * kStep, kStep);
    EXPECT_EQ(other.step(running()).state, DriveState::kFault) << code;
  }
  EXPECT_FALSE(sup.latched(FaultCode::kPeriodMismatch));

  sup.set_reported_period(50e-6, kStep);  // a 20 kHz stage against a 10 kHz drive
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  EXPECT_TRUE(sup.latched(FaultCode::kPeriodMismatch));
  EXPECT_DOUBLE_EQ(sup.status().reported_period_s, 50e-6) << "what the daemon's log names";
  sup.request_clear();
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault) << "not cleared while it lasts";
  sup.set_reported_period(100.0e-6, kStep);
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault) << "latched until a clear request";
  sup.request_clear();
  EXPECT_EQ(sup.step(running()).state, DriveState::kRunning) << "cleared once the periods agree";
  EXPECT_EQ(count(sup, FaultCode::kPeriodMismatch), 1U);

  // A drive period off the bus's grid (15 kHz: 66.67 us, between codes 266 and 267).
  Supervisor khz15(config(), 1.0 / 15000.0);
  for (const int code : {266, 267}) {
    khz15.set_reported_period(code * kStep, kStep);
    EXPECT_EQ(khz15.step(running()).state, DriveState::kRunning) << code;
  }
  khz15.set_reported_period(265 * kStep, kStep);
  EXPECT_EQ(khz15.step(running()).state, DriveState::kFault);

  // A stage that reports none (0), or a NaN: nothing is judged.
  for (const double none : {0.0, std::numeric_limits<double>::quiet_NaN(), -1e-4}) {
    Supervisor fresh(config(), kPeriod);
    fresh.set_reported_period(none, kStep);
    EXPECT_EQ(fresh.step(running()).state, DriveState::kRunning) << none;
    EXPECT_EQ(fresh.status().reported_period_s, 0.0);
  }
}

// A stage that keeps its gates off while the drive runs trips OUTPUT_FEEDBACK after a run of
// output_feedback_periods such samples; a sample lost now and then (the drive switches the
// gates off for that period alone) does not restart the count, the stage switching does, and
// 0 turns the check off.
// A healthy sample whose stage reports its gates switching (`on`) or not.
SupervisedSample gates(bool on) {
  SupervisedSample s = healthy();
  s.output_enabled = on;
  return s;
}

TEST(Supervisor, AStageThatKeepsItsGatesOffTripsOutputFeedback) {
  SupervisorConfig c = config();
  c.output_feedback_periods = 50;
  const SupervisedSample off = gates(false);
  SupervisorInput missing = running();
  missing.sample.reset();
  auto run = [&](Supervisor& sup, int samples, bool drop_some) {
    for (int k = 0; k < samples && !sup.latched(FaultCode::kOutputFeedback); ++k) {
      if (drop_some && k % 10 == 9) {
        sup.step(missing);
      }
      sup.step(running(off));
    }
  };
  Supervisor sup(c, kPeriod);
  sup.step(running());
  run(sup, 49, true);
  EXPECT_FALSE(sup.latched(FaultCode::kOutputFeedback));
  run(sup, 1, false);
  EXPECT_TRUE(sup.latched(FaultCode::kOutputFeedback)) << "50 samples with the gates off, a few lost between them";
  EXPECT_FALSE(sup.status().power_stage_enabled);

  Supervisor switching(c, kPeriod);
  for (int k = 0; k < 200; ++k) {
    switching.step(running(k % 40 == 39 ? healthy() : off));  // the stage switches now and then
  }
  EXPECT_FALSE(switching.latched(FaultCode::kOutputFeedback));

  c.output_feedback_periods = 0;
  Supervisor unjudged(c, kPeriod);
  run(unjudged, 500, false);
  EXPECT_FALSE(unjudged.latched(FaultCode::kOutputFeedback));
}

// The other way round: a stage that reports its gates switching while the drive holds them off
// (in INIT, in standby, in a fault) trips OUTPUT_FEEDBACK after the same run of samples, its value
// the count made negative; a stage that follows the drive's enable a sample or two late does not.
TEST(Supervisor, AStageThatSwitchesWhileHeldOffTripsOutputFeedback) {
  SupervisorConfig c = config();
  c.output_feedback_periods = 50;
  SupervisorInput held_off = running(gates(true));
  held_off.enable_requested = false;  // standby: the drive holds the gates off
  Supervisor sup(c, kPeriod);
  for (int k = 0; k < 49; ++k) {
    sup.step(held_off);
  }
  EXPECT_FALSE(sup.latched(FaultCode::kOutputFeedback));
  sup.step(held_off);
  EXPECT_TRUE(sup.latched(FaultCode::kOutputFeedback)) << "50 samples with the gates on while held off";
  EXPECT_FALSE(sup.status().power_stage_enabled);

  Supervisor init(c, kPeriod);
  SupervisorInput powering_up = running(gates(true));
  powering_up.frontend_ready = false;  // INIT: the offsets wait for samples with the gates off
  for (int k = 0; k < 60; ++k) {
    init.step(powering_up);
  }
  EXPECT_TRUE(init.latched(FaultCode::kOutputFeedback)) << "a stuck report must not hold INIT without a word";

  Supervisor following(c, kPeriod);
  following.step(running(gates(true)));
  for (int k = 0; k < 200; ++k) {
    // Enabled and disabled in turns of 40 samples; the stage follows two samples late.
    const bool enabled = (k / 40) % 2 == 0;
    const bool stage_on = ((k - 2 < 0 ? 0 : k - 2) / 40) % 2 == 0;
    SupervisorInput in = running(gates(stage_on));
    in.enable_requested = enabled;
    following.step(in);
  }
  EXPECT_FALSE(following.latched(FaultCode::kOutputFeedback));
}

// A stop asked for in a period without a sample does not clear a fault judged on the samples'
// readings: nothing showed its cause gone. The next sample that does clears it.
TEST(Supervisor, AStopWithoutASampleKeepsTheFaultsJudgedOnSamples) {
  Supervisor sup(config(), kPeriod);
  sup.step(running());
  SupervisedSample hot = healthy();
  hot.i_A = {900.0, -450.0, -450.0};
  sup.step(running(hot));
  ASSERT_TRUE(sup.latched(FaultCode::kOvercurrent));
  SupervisorInput silent = running();
  silent.sample.reset();
  sup.request_clear();
  sup.step(silent);
  EXPECT_TRUE(sup.latched(FaultCode::kOvercurrent)) << "cleared in a period without a sample";
  EXPECT_EQ(count(sup, FaultCode::kOvercurrent), 1U);
  sup.request_clear();
  sup.step(running());
  EXPECT_FALSE(sup.latched(FaultCode::kOvercurrent)) << "a healthy sample and a stop clear it";
  EXPECT_EQ(count(sup, FaultCode::kOvercurrent), 1U) << "latched once, not again";
}

TEST(Supervisor, TripIsImmediateAndLatched) {
  Supervisor sup(config(), kPeriod);
  sup.step(running());
  sup.trip(FaultCode::kInternal);
  EXPECT_EQ(sup.status().state, DriveState::kFault);
  EXPECT_FALSE(sup.status().power_stage_enabled);
  EXPECT_EQ(sup.step(running()).state, DriveState::kFault);
  sup.request_clear();
  EXPECT_EQ(sup.step(running()).state, DriveState::kRunning);
  EXPECT_EQ(count(sup, FaultCode::kInternal), 1U);
}

TEST(Supervisor, SeveralFaultsAtOnceAreEachLatchedAndTheFirstIsKept) {
  Supervisor sup(config(), kPeriod);
  sup.step(running(with_currents(181.0, 0.0, 0.0)));  // over-current and current sum
  EXPECT_TRUE(sup.latched(FaultCode::kOvercurrent));
  EXPECT_TRUE(sup.latched(FaultCode::kCurrentSum));
  EXPECT_EQ(sup.status().first_fault, FaultCode::kOvercurrent);
}

// The controller's own last line: a zero or NaN DC bus, or NaN currents, never reach a duty
// cycle, whatever the caller does.
TEST(DriveControllerSafety, ImplausibleInputGivesTheSafeOutput) {
  DriveConfig c;
  DriveController drive(c);
  DriveCommand cmd;
  cmd.mode = DriveMode::kTorque;
  cmd.torque_ref_Nm = 10.0;
  DriveInput in;
  in.i_A = {1.0, -0.5, -0.5};
  in.vdc_V = 650.0;
  for (int k = 0; k < 10; ++k) {
    ASSERT_TRUE(drive.step(in, cmd).enable);
  }
  for (const double vdc : {0.0, -1.0, kNan, std::numeric_limits<double>::infinity()}) {
    in.vdc_V = vdc;
    const DriveOutput& out = drive.step(in, cmd);
    EXPECT_FALSE(out.enable) << "vdc " << vdc;
    for (const double d : out.duty) {
      EXPECT_TRUE(std::isfinite(d)) << "vdc " << vdc;
    }
  }
  in.vdc_V = 650.0;
  in.i_A.b = kNan;
  EXPECT_FALSE(drive.step(in, cmd).enable);
  // Usable again, after samples were lost (the node compares the sequences): the first sample
  // locates the rotor afresh (the shaft may have turned on), the bridge switches from the
  // second, once the tracker has the speed too.
  in.i_A.b = -0.5;
  in.continuous = false;
  EXPECT_FALSE(drive.step(in, cmd).enable);
  in.continuous = true;
  EXPECT_TRUE(drive.step(in, cmd).enable);
  // A sample that follows the last one used (a slow lockstep power stage, no sample lost): the
  // tracker goes on as it was.
  in.vdc_V = 0.0;
  EXPECT_FALSE(drive.step(in, cmd).enable);
  in.vdc_V = 650.0;
  EXPECT_TRUE(drive.step(in, cmd).enable);
}

}  // namespace
}  // namespace pmsm::core
