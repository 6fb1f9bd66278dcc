// libFuzzer target: the CAN protocol's receive side, as a daemon, a plant and a monitor meet
// it on a bus anyone can write to. The input is a sequence of frames; each goes through
// decode_any (monitors), a DaemonReceiver (sensor samples and the three E2E-protected command
// streams, alive counters included) and a PlantReceiver (inverter commands).
//
// Checks beyond "no crash, no undefined behaviour" (ASan + UBSan):
//   - every non-command message decode_any accepts re-encodes, and decoding that frame again
//     and re-encoding it gives the same bytes (decode and encode agree on the layout);
//   - every frame a receiver accepts is one decode_any accepts as the same message type;
//   - a receiver's counters add up to the frames it was given.
#include <fuzzer/FuzzedDataProvider.h>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <type_traits>
#include <variant>

#include "pmsm/hal/codec.hpp"

namespace protocol = pmsm::hal::protocol;
using pmsm::hal::CanFrame;

namespace {

template <class M>
concept FreeEncodable = requires(const M& m, protocol::NodeId node, CanFrame& f) {
  { protocol::encode(m, node, f) } -> std::same_as<protocol::EncodeStatus>;
};

// decode -> encode -> decode -> encode gives the same bytes twice.
void check_round_trip(const protocol::AnyDecoded& first) {
  std::visit(
      [&](const auto& message) {
        using M = std::decay_t<decltype(message)>;
        if constexpr (FreeEncodable<M>) {
          CanFrame once;
          if (protocol::encode(message, first.node, once) == protocol::EncodeStatus::kOk) {
            protocol::AnyDecoded second;
            if (protocol::decode_any(once, second) != protocol::DecodeStatus::kOk || second.type != first.type) {
              std::abort();  // a frame the encoder wrote is not one the decoder reads
            }
            CanFrame twice;
            if (std::visit([&](const auto& m2) {
                  using M2 = std::decay_t<decltype(m2)>;
                  if constexpr (std::is_same_v<M2, M>) {
                    return protocol::encode(m2, second.node, twice);
                  } else {
                    return protocol::EncodeStatus::kOk;
                  }
                }, second.message) == protocol::EncodeStatus::kOk &&
                (once.length != twice.length || std::memcmp(once.data.data(), twice.data.data(), once.length) != 0)) {
              std::abort();  // encode(decode(x)) is not a fixed point
            }
          }
        }
      },
      first.message);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzedDataProvider in(data, size);
  const auto node = static_cast<protocol::NodeId>(in.ConsumeIntegralInRange<int>(0, protocol::kMaxNodeId));
  const auto max_delta = in.ConsumeIntegralInRange<std::uint8_t>(1, 15);
  protocol::DaemonReceiver daemon(node, max_delta);
  protocol::PlantReceiver plant(node);
  std::uint64_t frames = 0;
  std::int64_t now_ns = 0;
  // Every frame goes to all three receivers.
  auto receive_all = [&](const CanFrame& f, std::int64_t now_ns_) {
    protocol::AnyDecoded any;
    const protocol::DecodeStatus any_status = protocol::decode_any(f, any);
    if (any_status == protocol::DecodeStatus::kOk) {
      check_round_trip(any);
    }
    const protocol::DaemonInput got = daemon.receive(f, std::chrono::nanoseconds(now_ns_));
    if (!std::holds_alternative<protocol::Rejected>(got) && any_status != protocol::DecodeStatus::kOk) {
      std::abort();  // the daemon accepted what the stateless decoder refuses
    }
    const protocol::PlantInput plant_got = plant.receive(f);
    if (std::holds_alternative<pmsm::hal::InverterCommand>(plant_got) &&
        (any_status != protocol::DecodeStatus::kOk || any.type != protocol::MessageType::kInverterCommand)) {
      std::abort();
    }
  };
  protocol::CommandSender supervisor(node);
  while (in.remaining_bytes() > 0) {
    CanFrame f;
    const auto flags = in.ConsumeIntegral<std::uint8_t>();
    if ((flags & 0x10U) != 0) {
      // A command as a supervisor sends it (valid CRC and counter), fields from the input,
      // then perhaps one bit flipped: random bytes alone almost never pass the CRC, and the
      // accept paths and the counter checks are what this target is for.
      switch (in.ConsumeIntegralInRange<int>(0, 2)) {
        case 0: {
          protocol::DriveCommand c;
          c.enable = in.ConsumeBool();
          c.mode = static_cast<protocol::DriveMode>(in.ConsumeIntegralInRange<int>(0, 3));
          c.speed_setpoint_rad_s = in.ConsumeFloatingPoint<double>();
          c.torque_setpoint_Nm = in.ConsumeFloatingPoint<double>();
          (void)supervisor.encode(c, f);
          break;
        }
        case 1: {
          protocol::InjectionCommand c;
          c.method = static_cast<protocol::InjectionMethod>(in.ConsumeIntegralInRange<int>(0, 5));
          c.amplitude_A = in.ConsumeFloatingPoint<double>();
          c.interval_s = in.ConsumeFloatingPoint<double>();
          c.request_now = in.ConsumeBool();
          (void)supervisor.encode(c, f);
          break;
        }
        default: {
          protocol::CalibrationCommand c;
          c.action = static_cast<protocol::CalibrationAction>(in.ConsumeIntegralInRange<int>(0, 3));
          c.known_temp_C = in.ConsumeFloatingPoint<double>();
          (void)supervisor.encode(c, f);
          break;
        }
      }
      if ((flags & 0x20U) != 0 && f.length > 0) {
        const auto bit = in.ConsumeIntegralInRange<unsigned>(0, f.length * 8U - 1U);
        f.data[bit / 8U] ^= static_cast<std::uint8_t>(1U << (bit % 8U));
      }
      if ((flags & 0x40U) != 0) {
        f.id ^= 1U << in.ConsumeIntegralInRange<unsigned>(0, 10);  // another node or message
      }
      now_ns += in.ConsumeIntegralInRange<std::int64_t>(0, 1'000'000'000);
      ++frames;
      receive_all(f, now_ns);
      continue;
    }
    f.fd = (flags & 1U) != 0;
    f.extended = (flags & 2U) != 0;
    f.error = (flags & 4U) != 0;
    f.bitrate_switch = (flags & 8U) != 0;
    f.id = f.extended ? in.ConsumeIntegral<std::uint32_t>() & 0x1FFFFFFFU : in.ConsumeIntegral<std::uint16_t>() & 0x7FFU;
    f.length = in.ConsumeIntegralInRange<std::uint8_t>(
        0, static_cast<std::uint8_t>(f.fd ? CanFrame::kMaxFdLength : CanFrame::kMaxClassicLength));
    const auto bytes = in.ConsumeBytes<std::uint8_t>(f.length);
    if (!bytes.empty()) {
      std::memcpy(f.data.data(), bytes.data(), bytes.size());
    }
    now_ns += in.ConsumeIntegralInRange<std::int64_t>(0, 1'000'000'000);
    ++frames;
    receive_all(f, now_ns);
  }
  std::uint64_t daemon_total = 0;
  for (std::uint64_t n : daemon.counters().by_status) daemon_total += n;
  std::uint64_t plant_total = 0;
  for (std::uint64_t n : plant.counters().by_status) plant_total += n;
  if (daemon_total != frames || plant_total != frames) {
    std::abort();  // a frame went uncounted
  }
  return 0;
}
