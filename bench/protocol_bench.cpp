// Codec speed for the frames that cross the bus every period (DESIGN §9): SENSOR_SAMPLE and
// INVERTER_COMMAND encode/decode, the E2E CRC of command frames, and the receivers each
// process runs per frame (DaemonReceiver for samples and commands, PlantReceiver).
#include <benchmark/benchmark.h>

#include <array>
#include <chrono>
#include <variant>

#include "pmsm/hal/codec.hpp"

namespace {

namespace hal = pmsm::hal;
namespace protocol = pmsm::hal::protocol;

hal::SensorSample sample() {
  hal::SensorSample s;
  s.sequence = 123456;
  s.phase_current_adc = {205, -102, -103};
  s.encoder_count = 8192;
  s.dc_bus_adc = 2662;
  s.flags = hal::kSensorOutputEnabled;
  return s;
}

hal::InverterCommand command() {
  hal::InverterCommand c;
  c.sequence = 123456;
  c.duty = {32768, 16384, 49151};
  c.enable = true;
  return c;
}

void BM_EncodeSensorSample(benchmark::State& state) {
  hal::SensorSample s = sample();
  hal::CanFrame f;
  for (auto _ : state) {
    ++s.sequence;
    benchmark::DoNotOptimize(protocol::encode(s, 0, f));
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_EncodeSensorSample);

void BM_DecodeSensorSample(benchmark::State& state) {
  hal::CanFrame f;
  (void)protocol::encode(sample(), 0, f);
  hal::SensorSample s;
  for (auto _ : state) {
    benchmark::DoNotOptimize(protocol::decode(f, 0, s));
    benchmark::DoNotOptimize(s);
  }
}
BENCHMARK(BM_DecodeSensorSample);

void BM_EncodeInverterCommand(benchmark::State& state) {
  hal::InverterCommand c = command();
  hal::CanFrame f;
  for (auto _ : state) {
    ++c.sequence;
    benchmark::DoNotOptimize(protocol::encode(c, 0, f));
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_EncodeInverterCommand);

void BM_DecodeInverterCommand(benchmark::State& state) {
  hal::CanFrame f;
  (void)protocol::encode(command(), 0, f);
  hal::InverterCommand c;
  for (auto _ : state) {
    benchmark::DoNotOptimize(protocol::decode(f, 0, c));
    benchmark::DoNotOptimize(c);
  }
}
BENCHMARK(BM_DecodeInverterCommand);

void BM_E2eCrc(benchmark::State& state) {
  std::array<std::uint8_t, 8> payload{0, 0x10, 1, 0xC4, 9, 0x58, 2, 0};
  for (auto _ : state) {
    ++payload[2];
    benchmark::DoNotOptimize(protocol::e2e_crc(0x050, payload));
  }
}
BENCHMARK(BM_E2eCrc);

void BM_PlantReceiverReceive(benchmark::State& state) {
  protocol::PlantReceiver receiver(0);
  hal::CanFrame f;
  (void)protocol::encode(command(), 0, f);
  for (auto _ : state) {
    benchmark::DoNotOptimize(receiver.receive(f));
  }
}
BENCHMARK(BM_PlantReceiverReceive);

void BM_DaemonReceiverReceiveSample(benchmark::State& state) {
  protocol::DaemonReceiver receiver(0);
  hal::CanFrame f;
  (void)protocol::encode(sample(), 0, f);
  std::int64_t now_ns = 0;
  for (auto _ : state) {
    now_ns += 100'000;
    benchmark::DoNotOptimize(receiver.receive(f, std::chrono::nanoseconds{now_ns}));
  }
}
BENCHMARK(BM_DaemonReceiverReceiveSample);

// A DRIVE_COMMAND stream with advancing alive counters: CRC check + counter state machine.
void BM_DaemonReceiverReceiveDriveCommand(benchmark::State& state) {
  protocol::CommandSender sender(0);
  std::array<hal::CanFrame, protocol::kAliveCounterModulo> frames{};
  protocol::DriveCommand dc;
  dc.enable = true;
  dc.mode = protocol::DriveMode::kSpeed;
  dc.speed_setpoint_rad_s = 157.08;
  for (hal::CanFrame& f : frames) {
    (void)sender.encode(dc, f);
  }
  protocol::DaemonReceiver receiver(0);
  std::size_t i = 0;
  std::int64_t now_ns = 0;
  for (auto _ : state) {
    now_ns += 20'000'000;
    const protocol::DaemonInput in = receiver.receive(frames[i], std::chrono::nanoseconds{now_ns});
    benchmark::DoNotOptimize(in);
    i = (i + 1) % frames.size();
  }
  if (receiver.counters().rejected() != 0) {
    state.SkipWithError("drive commands were rejected");
  }
}
BENCHMARK(BM_DaemonReceiverReceiveDriveCommand);

}  // namespace
