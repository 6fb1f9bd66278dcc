// The frame codec shared by pmsm-thermald and pmsm-plant: typed encode/decode of every
// message of protocol.hpp, the command-stream alive-counter check, counted rejections, and
// per-role receivers.
//
// Real-time use: every function and method here is noexcept, allocates nothing, logs
// nothing and takes well under a microsecond (the two fast-loop frames run every 100 us).
//
// Sending:
//   CanFrame f;
//   protocol::encode(sample, node, f);              // plant: SENSOR_SAMPLE
//   protocol::encode(command, node, f);             // daemon: INVERTER_COMMAND
//   protocol::encode(thermal_estimate, node, f);    // daemon: telemetry
//   CommandSender tx(node); tx.encode(drive_command, f);  // supervisor: keeps the alive counters
// Receiving:
//   DaemonReceiver rx(node);                        // daemon: samples and commands
//   auto in = rx.receive(frame, now);               // std::variant<Rejected, SensorSample, ...>
//   PlantReceiver prx(node);                        // plant: inverter commands
//   decode_any(frame, decoded);                     // monitors: any message of any node
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string_view>
#include <variant>

#include "pmsm/hal/can_frame.hpp"
#include "pmsm/hal/messages.hpp"
#include "pmsm/hal/protocol.hpp"

namespace pmsm::hal::protocol {

// ---------------------------------------------------------------------------------------
// Results and counters
// ---------------------------------------------------------------------------------------

// Outcome of an encode; the worst that happened to any signal. The frame is written in
// full unless the status is kInvalidNode.
enum class EncodeStatus : std::uint8_t {
  kOk,
  kSaturated,     // a value lay outside its signal's [minimum, maximum] and was clamped; the
                  // frame is valid (telemetry may be sent; a command sender should not)
  kInvalidValue,  // a value was NaN/infinite (and not guarded by a cleared validity bit) or
                  // an enum outside its value table: that signal holds 0. Do not send.
  kInvalidNode,   // node id > 15: nothing written. Do not send.
};

[[nodiscard]] std::string_view to_string(EncodeStatus status) noexcept;

// Outcome of a decode. Everything but kOk is a rejection with its own counted reason.
enum class DecodeStatus : std::uint8_t {
  kOk,
  kUnknownId,         // not a protocol ID, not one this role receives, an extended-ID or error frame
  kWrongNode,         // a protocol message, but for another node
  kWrongFrameFormat,  // classic CAN where CAN FD is defined, or vice versa
  kWrongLength,       // data length differs from the definition
  kBadCrc,            // command frame whose CRC-8 does not match
  kRepeatedCounter,   // command frame with the same alive counter as the last accepted one
  kCounterJump,       // alive counter advanced by more than the allowed delta (lost or stale)
  kOutOfRange,        // a signal outside its [minimum, maximum]
  kStreamDisturbed,   // a command that passed every check, held back: its stream carried corrupt
                      // frames just before (DaemonReceiver, "disturbed"); a stop is not held back
};
inline constexpr std::size_t kDecodeStatusCount = 10;

[[nodiscard]] std::string_view to_string(DecodeStatus status) noexcept;  // "wrong_length", ...
[[nodiscard]] std::string_view describe(DecodeStatus status) noexcept;   // a sentence (docs)

// Counts of decode outcomes. Plain data: the owning (RT) thread writes it; hand copies to
// other threads.
struct DecodeCounters {
  std::array<std::uint64_t, kDecodeStatusCount> by_status{};

  constexpr void count(DecodeStatus status) noexcept { ++by_status[static_cast<std::size_t>(status)]; }
  [[nodiscard]] constexpr std::uint64_t operator[](DecodeStatus status) const noexcept {
    return by_status[static_cast<std::size_t>(status)];
  }
  [[nodiscard]] constexpr std::uint64_t accepted() const noexcept { return (*this)[DecodeStatus::kOk]; }
  [[nodiscard]] constexpr std::uint64_t rejected() const noexcept {
    std::uint64_t sum = 0;
    for (std::size_t i = 1; i < by_status.size(); ++i) {
      sum += by_status[i];
    }
    return sum;
  }
};

// ---------------------------------------------------------------------------------------
// E2E: CRC and alive counter
// ---------------------------------------------------------------------------------------

// CRC-8 SAE J1850 over the data ID (the 11-bit CAN ID, low byte then high byte) followed by
// bytes 1..7 of an 8-byte command payload. Byte 0 carries the result.
[[nodiscard]] std::uint8_t e2e_crc(std::uint32_t can_id, std::span<const std::uint8_t, 8> payload) noexcept;

inline constexpr std::uint8_t kAliveCounterModulo = 16;
inline constexpr std::uint8_t kDefaultMaxCounterDelta = 2;  // tolerates one lost frame

// The alive-counter state machine of one command stream (AUTOSAR E2E profile 1 style):
//   - the first frame after construction or reset() is accepted whatever its counter;
//   - then the counter must advance by 1..max_delta (mod 16): kOk;
//   - an unchanged counter is kRepeatedCounter (state kept);
//   - a larger advance is kCounterJump; the stream re-synchronises on that counter, so the
//     next consecutive frame is accepted again (one frame of proof that the sender is live).
class AliveCounterCheck {
 public:
  // max_delta is clamped to 1..14 (15 would accept a frame one step old).
  explicit AliveCounterCheck(std::uint8_t max_delta = kDefaultMaxCounterDelta) noexcept;

  [[nodiscard]] DecodeStatus check(std::uint8_t counter) noexcept;
  void reset() noexcept { synchronized_ = false; }
  [[nodiscard]] bool synchronized() const noexcept { return synchronized_; }
  [[nodiscard]] std::uint8_t max_delta() const noexcept { return max_delta_; }

 private:
  std::uint8_t max_delta_;
  std::uint8_t last_ = 0;
  bool synchronized_ = false;
};

// ---------------------------------------------------------------------------------------
// Stateless encode / decode, one overload per message
// ---------------------------------------------------------------------------------------
// decode() checks, in this order: ID (kUnknownId), node (kWrongNode), FD/classic
// (kWrongFrameFormat), length (kWrongLength), CRC for commands (kBadCrc), value ranges
// (kOutOfRange). `out` is written only on kOk. The alive counter of a command is returned
// for the caller's AliveCounterCheck (the receivers below do that for you).

// Fast loop (CAN FD).
EncodeStatus encode(const InverterCommand& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const SensorSample& message, NodeId node, CanFrame& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, InverterCommand& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, SensorSample& out) noexcept;

// Commands (classic, E2E-protected).
EncodeStatus encode(const DriveCommand& message, NodeId node, std::uint8_t alive_counter, CanFrame& out) noexcept;
EncodeStatus encode(const InjectionCommand& message, NodeId node, std::uint8_t alive_counter, CanFrame& out) noexcept;
EncodeStatus encode(const CalibrationCommand& message, NodeId node, std::uint8_t alive_counter, CanFrame& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, DriveCommand& out, std::uint8_t& alive_counter) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, InjectionCommand& out, std::uint8_t& alive_counter) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, CalibrationCommand& out, std::uint8_t& alive_counter) noexcept;

// Telemetry (classic) and bench frames (classic).
EncodeStatus encode(const FaultReport& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const DriveStatus& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const ThermalEstimate& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const ResistanceEstimate& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const InjectionReport& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const Heartbeat& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const ReceiveStatus& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const LoopTiming& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const TruthThermal& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const TruthElectrical& message, NodeId node, CanFrame& out) noexcept;
EncodeStatus encode(const PlantStatus& message, NodeId node, CanFrame& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, FaultReport& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, DriveStatus& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, ThermalEstimate& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, ResistanceEstimate& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, InjectionReport& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, Heartbeat& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, ReceiveStatus& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, LoopTiming& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, TruthThermal& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, TruthElectrical& out) noexcept;
[[nodiscard]] DecodeStatus decode(const CanFrame& frame, NodeId node, PlantStatus& out) noexcept;

// The plant's truth frames from its TruthSample (the ambient temperature is not part of it).
[[nodiscard]] TruthThermal truth_thermal_from(const TruthSample& truth, double ambient_temp_C) noexcept;
[[nodiscard]] TruthElectrical truth_electrical_from(const TruthSample& truth) noexcept;

// ---------------------------------------------------------------------------------------
// Any message (monitors, bench, tools)
// ---------------------------------------------------------------------------------------

// Alternatives in MessageType order: AnyMessage::index() == static_cast<size_t>(type).
using AnyMessage =
    std::variant<InverterCommand, SensorSample, DriveCommand, InjectionCommand, CalibrationCommand,
                 FaultReport, DriveStatus, ThermalEstimate, ResistanceEstimate, InjectionReport,
                 Heartbeat, ReceiveStatus, LoopTiming, TruthThermal, TruthElectrical, PlantStatus>;

struct AnyDecoded {
  MessageType type = MessageType::kInverterCommand;
  NodeId node = 0;
  AnyMessage message;
  std::uint8_t alive_counter = 0;  // commands only
};

// Decodes a frame of any message and any node (no alive-counter state: a monitor cannot
// know which stream it joined). Same checks as decode(), minus the node. `out`'s type, node and
// alive counter are set on kOk, and on kOutOfRange of a command whose CRC held: a genuine frame
// with a bad value still advances its stream (docs/protocol.md), so a monitor that keeps the
// counters must count it as the daemon does; `out.message` is then not to be read.
[[nodiscard]] DecodeStatus decode_any(const CanFrame& frame, AnyDecoded& out) noexcept;

// ---------------------------------------------------------------------------------------
// Receivers: one per role, with counted rejections
// ---------------------------------------------------------------------------------------

struct Rejected {
  DecodeStatus reason = DecodeStatus::kUnknownId;
  std::uint32_t can_id = 0;
};

enum class CommandStream : std::uint8_t { kDrive, kInjection, kCalibration };
inline constexpr std::size_t kCommandStreamCount = 3;

using DaemonInput = std::variant<Rejected, SensorSample, DriveCommand, InjectionCommand, CalibrationCommand>;

// A command stream is *disturbed* while kDisturbedErrors of its frames failed an integrity check
// (CRC, length, frame format) within kDisturbedWindow: a frame of it that passes every check is
// then not acted on (kStreamDisturbed), though its alive counter is followed, unless it carries
// no new order: a command that can only take the drive towards its safe state (a DRIVE_COMMAND
// that disables, a CALIBRATION_COMMAND that starts nothing: a garbage frame passing as one costs
// a stop, never a start, and a supervisor's stop is heard through any disturbance), or a
// DRIVE_COMMAND that repeats the last one acted on (enable, mode and set-points alike: it
// changes nothing but keeps the command timeout from tripping while a supervisor holds its
// set-point). A genuine supervisor on a healthy bus sends no corrupt frame (CAN's own CRC drops
// what the wire corrupts), so two of them mean a device sending garbage on this node's command
// ID, among which one frame in 256 passes the CRC-8 and one in 2,000 the alive counter too: by
// chance, not by intent. One corrupt frame alone (a supervisor's slip) holds nothing back.
// (AUTOSAR's E2E state machine likewise judges a window of check results before the data are
// used, and the application then keeps the last valid value for a tolerance time.) A babbler
// that keeps on holds a changing set-point back until the command timeout trips; one slower than
// two frames a second is not caught: about one of its random frames in 80,000 could start
// something.
inline constexpr std::chrono::nanoseconds kDisturbedWindow = std::chrono::seconds(1);
inline constexpr std::size_t kDisturbedErrors = 2;

// The daemon's receive side for one node: sensor samples and the three command streams.
// Tracks when each message type was last accepted, so that the daemon's timeouts (sensor
// timeout, command timeout) are one call: age(type, now) > timeout. Time is whatever
// monotonic base the caller passes (e.g. the frame's receive timestamp); no clock is read.
class DaemonReceiver {
 public:
  explicit DaemonReceiver(NodeId node, std::uint8_t max_counter_delta = kDefaultMaxCounterDelta) noexcept;

  [[nodiscard]] DaemonInput receive(const CanFrame& frame, std::chrono::nanoseconds now) noexcept;

  // Time since `type` was last accepted; nullopt if never.
  [[nodiscard]] std::optional<std::chrono::nanoseconds> age(MessageType type,
                                                            std::chrono::nanoseconds now) const noexcept;
  [[nodiscard]] std::optional<std::chrono::nanoseconds> last_accepted(MessageType type) const noexcept;

  // Forgets a command stream's alive counter: its next frame is accepted as a first frame.
  // For example after a command timeout, so that a restarted supervisor is heard at once
  // (at the price of accepting one frame without a counter history).
  void resync(CommandStream stream) noexcept;

  // Whether `stream` is disturbed at `now` (kDisturbedErrors integrity failures within
  // kDisturbedWindow before it). resync() leaves this history alone.
  [[nodiscard]] bool disturbed(CommandStream stream, std::chrono::nanoseconds now) const noexcept;

  [[nodiscard]] NodeId node() const noexcept { return node_; }
  [[nodiscard]] const DecodeCounters& counters() const noexcept { return total_; }
  // Per message type; frames not attributable to a message type count only in counters().
  [[nodiscard]] const DecodeCounters& counters(MessageType type) const noexcept;

 private:
  template <class Command>
  DaemonInput receive_command(const CanFrame& frame, CommandStream stream, std::chrono::nanoseconds now) noexcept;
  DaemonInput reject(const CanFrame& frame, const MessageDef* def, DecodeStatus reason) noexcept;
  void accept(MessageType type, std::chrono::nanoseconds now) noexcept;

  // The times of a command stream's last kDisturbedErrors integrity failures (a ring).
  struct IntegrityErrors {
    std::array<std::chrono::nanoseconds, kDisturbedErrors> at{};
    std::uint64_t count = 0;
  };
  // A DRIVE_COMMAND frame's order: its payload but the CRC and the alive counter.
  [[nodiscard]] static std::array<std::uint8_t, 7> drive_command_payload(const CanFrame& frame) noexcept;

  NodeId node_;
  std::array<AliveCounterCheck, kCommandStreamCount> streams_;
  std::array<IntegrityErrors, kCommandStreamCount> integrity_errors_{};
  std::optional<std::array<std::uint8_t, 7>> last_drive_command_;  // the last acted on (drive_command_payload)
  std::array<DecodeCounters, kMessageCount> per_type_{};
  std::array<std::optional<std::chrono::nanoseconds>, kMessageCount> last_accepted_{};
  DecodeCounters total_{};
};

using PlantInput = std::variant<Rejected, InverterCommand>;

// The plant's receive side for one node: inverter commands.
class PlantReceiver {
 public:
  explicit PlantReceiver(NodeId node) noexcept : node_(node) {}

  [[nodiscard]] PlantInput receive(const CanFrame& frame) noexcept;

  [[nodiscard]] NodeId node() const noexcept { return node_; }
  [[nodiscard]] const DecodeCounters& counters() const noexcept { return counters_; }

 private:
  NodeId node_;
  DecodeCounters counters_{};
};

// The supervisor's send side for one node: stamps each command stream's alive counter.
// The counter advances with every frame encoded kOk, the only commands to send (a saturated one
// is not sent: docs/protocol.md); send each of those, or the receiver sees a gap (tolerated up to
// its max delta).
class CommandSender {
 public:
  explicit CommandSender(NodeId node) noexcept : node_(node) {}

  EncodeStatus encode(const DriveCommand& message, CanFrame& out) noexcept;
  EncodeStatus encode(const InjectionCommand& message, CanFrame& out) noexcept;
  EncodeStatus encode(const CalibrationCommand& message, CanFrame& out) noexcept;

  [[nodiscard]] std::uint8_t next_counter(CommandStream stream) const noexcept {
    return counters_[static_cast<std::size_t>(stream)];
  }

 private:
  void advance(CommandStream stream, EncodeStatus status) noexcept;

  NodeId node_;
  std::array<std::uint8_t, kCommandStreamCount> counters_{};
};

}  // namespace pmsm::hal::protocol
