// pmsm-thermal command's reading of the daemon's answers (tools/cli/daemon_answers.hpp), on
// frames built with the codec: what makes the command's exit status 3 (the daemon refused what
// was asked) and what does not.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "daemon_answers.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol.hpp"

namespace pmsm::app {
namespace {

constexpr int kNode = 2;

// A message as the daemon of `node` sends it.
template <class Message>
hal::CanFrame encoded(const Message& m, int node = kNode) {
  hal::CanFrame f;
  EXPECT_EQ(protocol::encode(m, static_cast<protocol::NodeId>(node), f), protocol::EncodeStatus::kOk);
  return f;
}

hal::CanFrame estimate(bool calibrating, protocol::CalibrationResult result, int node = kNode) {
  protocol::ThermalEstimate t;
  t.valid = true;
  t.winding_temp_C = 40.0;
  t.winding_temp_sigma_C = 1.0;
  t.calibrating = calibrating;
  t.calibration_result = result;
  return encoded(t, node);
}

hal::CanFrame heartbeat(double uptime_s) {
  protocol::Heartbeat h;
  h.uptime_s = uptime_s;
  return encoded(h);
}

hal::CanFrame receive_status(std::uint64_t counter_rejections, std::uint64_t other_rejections, protocol::DecodeStatus last,
                             std::uint16_t id) {
  protocol::ReceiveStatus r;
  r.rejected_counter = counter_rejections;
  r.rejected_other = other_rejections;
  r.last_rejection = static_cast<std::uint8_t>(last);
  r.last_rejected_id = id;
  return encoded(r);
}

struct Quiet {
  std::FILE* out = std::tmpfile();
  ~Quiet() { std::fclose(out); }
  Quiet() = default;
  Quiet(const Quiet&) = delete;
  Quiet& operator=(const Quiet&) = delete;
};

TEST(DaemonAnswers, ACalibrationThatEndsDoneIsNoRefusal) {
  Quiet q;
  DaemonAnswers a(kNode, true, q.out);
  a.read(estimate(false, protocol::CalibrationResult::kNone));
  a.read(estimate(true, protocol::CalibrationResult::kNone));
  a.read(estimate(false, protocol::CalibrationResult::kDone));
  EXPECT_FALSE(a.finish());
}

hal::CanFrame status(protocol::DriveState state) {
  protocol::DriveStatus s;
  s.state = state;
  return encoded(s);
}

std::string text_of(std::FILE* f) {
  std::rewind(f);
  std::string s;
  for (int c = std::fgetc(f); c != EOF; c = std::fgetc(f)) {
    s.push_back(static_cast<char>(c));
  }
  return s;
}

// A restarted daemon's result reads NONE (no calibration since its start): said as a restart,
// not as a calibration that ended NONE, and no refusal.
TEST(DaemonAnswers, AResultBackToNoneIsARestartNotARefusal) {
  Quiet q;
  DaemonAnswers a(kNode, true, q.out);
  a.read(estimate(false, protocol::CalibrationResult::kNone));
  a.read(estimate(true, protocol::CalibrationResult::kNone));
  a.read(estimate(false, protocol::CalibrationResult::kDone));
  a.read(estimate(false, protocol::CalibrationResult::kNone));
  EXPECT_FALSE(a.finish());
  const std::string text = text_of(q.out);
  EXPECT_NE(text.find("calibration result NONE again: the daemon started again"), std::string::npos) << text;
  EXPECT_EQ(text.find("calibration NONE\n"), std::string::npos) << text;
}

// A calibration a fault suspends is said to be suspended, once, not only "running".
TEST(DaemonAnswers, ACalibrationAFaultSuspendsIsSaidToBeSuspended) {
  Quiet q;
  DaemonAnswers a(kNode, true, q.out);
  a.read(estimate(false, protocol::CalibrationResult::kNone));
  a.read(estimate(true, protocol::CalibrationResult::kNone));
  a.read(status(protocol::DriveState::kFault));
  a.read(status(protocol::DriveState::kFault));
  const std::string text = text_of(q.out);
  EXPECT_NE(text.find("node 2: calibration running"), std::string::npos) << text;
  const auto at = text.find("node 2: calibration suspended: the drive is in FAULT");
  ASSERT_NE(at, std::string::npos) << text;
  EXPECT_EQ(text.find("calibration suspended", at + 30), std::string::npos) << "said once: " << text;
  EXPECT_FALSE(a.finish()) << "suspended is not refused";
  a.read(status(protocol::DriveState::kStandby));
  EXPECT_NE(text_of(q.out).find("calibration suspended: the drive is not enabled"), std::string::npos) << text_of(q.out);
}

TEST(DaemonAnswers, ACalibrationStillRunningAtTheEndIsNoRefusal) {
  Quiet q;
  DaemonAnswers a(kNode, true, q.out);
  a.read(estimate(false, protocol::CalibrationResult::kNone));
  a.read(estimate(true, protocol::CalibrationResult::kNone));
  EXPECT_FALSE(a.finish());
}

TEST(DaemonAnswers, ACalibrationThatEndsOtherwiseIsARefusal) {
  for (const auto result : {protocol::CalibrationResult::kRefused, protocol::CalibrationResult::kTimedOut,
                            protocol::CalibrationResult::kAborted}) {
    Quiet q;
    DaemonAnswers a(kNode, true, q.out);
    a.read(estimate(false, protocol::CalibrationResult::kNone));
    a.read(estimate(true, protocol::CalibrationResult::kNone));
    a.read(estimate(false, result));
    EXPECT_TRUE(a.finish()) << static_cast<int>(result);
  }
}

// The daemon's own calibration (calibrate_if_missing) ending TIMED_OUT during a run that asked
// for none is not this run's refusal.
TEST(DaemonAnswers, ACalibrationNotAskedForIsNotThisRunsRefusal) {
  Quiet q;
  DaemonAnswers a(kNode, false, q.out);
  a.read(estimate(false, protocol::CalibrationResult::kNone));
  a.read(estimate(true, protocol::CalibrationResult::kNone));
  a.read(estimate(false, protocol::CalibrationResult::kTimedOut));
  a.read(estimate(false, protocol::CalibrationResult::kRefused));
  EXPECT_FALSE(a.finish());
}

TEST(DaemonAnswers, ACalibrationRefusedAtOnceOrNeverSeenIsARefusal) {
  {
    Quiet q;
    DaemonAnswers a(kNode, true, q.out);
    a.read(estimate(false, protocol::CalibrationResult::kDone));  // an earlier calibration's result
    a.read(estimate(false, protocol::CalibrationResult::kRefused));
    EXPECT_TRUE(a.finish());
  }
  {
    Quiet q;
    DaemonAnswers a(kNode, true, q.out);
    a.read(estimate(false, protocol::CalibrationResult::kNone));
    a.read(estimate(true, protocol::CalibrationResult::kNone, kNode + 1));  // another node's
    EXPECT_TRUE(a.finish()) << "asked for and never seen";
  }
  {
    Quiet q;
    DaemonAnswers a(kNode, false, q.out);  // none asked for: nothing to see
    a.read(estimate(false, protocol::CalibrationResult::kNone));
    EXPECT_FALSE(a.finish());
  }
}

TEST(DaemonAnswers, ARejectedCommandIsARefusalButACounterResynchronisationIsNot) {
  const auto drive_id = static_cast<std::uint16_t>(0x040 + kNode);
  {
    Quiet q;
    DaemonAnswers a(kNode, false, q.out);
    a.read(receive_status(0, 0, protocol::DecodeStatus::kOk, 0));
    a.read(receive_status(1, 0, protocol::DecodeStatus::kRepeatedCounter, drive_id));  // the synchronising frame
    EXPECT_FALSE(a.finish());
  }
  {
    Quiet q;
    DaemonAnswers a(kNode, false, q.out);
    a.read(receive_status(0, 0, protocol::DecodeStatus::kOk, 0));
    a.read(receive_status(0, 1, protocol::DecodeStatus::kStreamDisturbed, drive_id));
    EXPECT_TRUE(a.finish());
  }
}

// Two supervisors on one node: their counters interleave and the daemon refuses most frames of
// both as repeated or jumped counters. Each run's synchronising frames are its allowance; more
// refusals are said once and make the exit status 3 (they went unsaid, exit 0, before).
TEST(DaemonAnswers, CounterRefusalsBeyondTheSynchronisingFramesAreAnotherSender) {
  const auto drive_id = static_cast<std::uint16_t>(0x040 + kNode);
  {
    Quiet q;
    DaemonAnswers a(kNode, false, q.out, 1);
    a.read(receive_status(0, 0, protocol::DecodeStatus::kOk, 0));
    a.read(receive_status(4, 0, protocol::DecodeStatus::kRepeatedCounter, drive_id));
    a.read(receive_status(9, 0, protocol::DecodeStatus::kCounterJump, drive_id));
    EXPECT_TRUE(a.finish());
    const std::string text = text_of(q.out);
    const auto at = text.find("node 2: the daemon refused 9 command frame(s) of this node for their alive counter, "
                              "more than this run's 1 synchronising or unsent frame(s): another supervisor is sending to node 2");
    EXPECT_NE(at, std::string::npos) << text;
    EXPECT_EQ(text.find("another supervisor", text.find("another supervisor") + 1), std::string::npos)
        << "said once: " << text;
  }
  {
    // Three streams started (a drive command, a calibration, an injection request): three
    // refusals are theirs; the counts wrap at 256 as RECEIVE_STATUS sends them.
    Quiet q;
    DaemonAnswers a(kNode, false, q.out, 3);
    a.read(receive_status(254, 0, protocol::DecodeStatus::kOk, 0));
    a.read(receive_status(1, 0, protocol::DecodeStatus::kRepeatedCounter, drive_id));
    EXPECT_FALSE(a.finish()) << text_of(q.out);
    a.read(receive_status(2, 0, protocol::DecodeStatus::kRepeatedCounter, drive_id));
    EXPECT_TRUE(a.finish()) << "254 -> 2 is four refusals, one more than three";
  }
  {
    // A daemon started again during the run counts from zero: a count that went down is no 200
    // refusals; from there its own count is the baseline. A frame this run could not send spent
    // its counter, and the jump that follows is this run's own.
    Quiet q;
    DaemonAnswers a(kNode, false, q.out, 1);
    a.read(heartbeat(3600.0));
    a.read(receive_status(200, 0, protocol::DecodeStatus::kRepeatedCounter, drive_id));
    a.read(receive_status(0, 0, protocol::DecodeStatus::kOk, 0));  // reads as 56 refusals until ...
    a.read(heartbeat(0.5));                                        // ... the restart is told
    a.read(receive_status(1, 0, protocol::DecodeStatus::kRepeatedCounter, drive_id));
    a.read(heartbeat(1.5));
    EXPECT_FALSE(a.finish()) << text_of(q.out);
    a.note_unsent_frame();
    a.read(receive_status(2, 0, protocol::DecodeStatus::kCounterJump, drive_id));
    EXPECT_FALSE(a.finish()) << text_of(q.out);
    a.read(receive_status(3, 0, protocol::DecodeStatus::kCounterJump, drive_id));
    EXPECT_TRUE(a.finish());
  }
  {
    // Refusals counted before this run's first RECEIVE_STATUS are another run's.
    Quiet q;
    DaemonAnswers a(kNode, false, q.out, 1);
    a.read(receive_status(200, 0, protocol::DecodeStatus::kRepeatedCounter, drive_id));
    a.read(receive_status(200, 0, protocol::DecodeStatus::kRepeatedCounter, drive_id));
    EXPECT_FALSE(a.finish());
  }
}

}  // namespace
}  // namespace pmsm::app
