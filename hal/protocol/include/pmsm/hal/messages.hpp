// Plain data exchanged between the drive controller and the plant (or the real power stage).
//
// These are the only types, besides the frame codec, that the plant emulator and the
// controller share (DESIGN §3): no behaviour, no physics, just what crosses the boundary.
// Quantities cross as a real sensor front end delivers them: ADC codes and encoder counts.
// Turning codes into amperes is the controller's job, with its own (nominal) calibration,
// so that the plant's gain and offset errors stay invisible to it as they would on hardware.
#pragma once

#include <array>
#include <cstdint>

namespace pmsm::hal {

// Bits of SensorSample::flags.
enum SensorFlag : std::uint8_t {
  kSensorOutputEnabled = 1U << 0,    // the inverter's gates are switching
  kSensorPhaseVoltageValid = 1U << 1, // phase_voltage_adc holds measurements
  kSensorHardwareOvercurrent = 1U << 2, // the power stage's own comparator tripped
  kSensorAmbientValid = 1U << 3,     // ambient_centi_C holds a reading
};

// One period's sensor readings, plant -> controller. Sampled at the start of period
// `sequence` (the middle of the PWM carrier, where the current ripple crosses its mean).
struct SensorSample {
  std::uint32_t sequence = 0;                     // period index k
  std::array<std::int16_t, 3> phase_current_adc{}; // signed codes about mid-scale, phases a b c
  std::uint16_t encoder_count = 0;                 // absolute mechanical angle, 0 .. 2^bits - 1
  std::uint16_t dc_bus_adc = 0;                    // unsigned DC-bus voltage code
  std::array<std::int16_t, 3> phase_voltage_adc{}; // phase-to-neutral voltages, if sensed
  std::uint8_t flags = 0;                          // SensorFlag bits
  std::int16_t ambient_centi_C = 0;                // ambient / coolant sensor, 0.01 C (if valid)
  // The power stage's PWM period, at which it samples, in steps of kPwmPeriodStep_s (12 bits on
  // the bus: up to 1023.75 us, below 1 kHz); 0: not reported. The drive checks it against its
  // own period.
  std::uint16_t pwm_period_code = 0;
};

// SensorSample::pwm_period_code's step and largest code (SENSOR_SAMPLE PwmPeriod: the codec
// checks that the signal says the same at compile time).
inline constexpr double kPwmPeriodStep_us = 0.25;
inline constexpr double kPwmPeriodStep_s = kPwmPeriodStep_us * 1e-6;
inline constexpr std::uint16_t kPwmPeriodMaxCode = 4095;  // 12 bits

// SensorSample::pwm_period_code for a PWM frequency: the nearest code, or 0 (not reported)
// when the period does not fit the field.
[[nodiscard]] inline std::uint16_t pwm_period_code(double pwm_frequency_Hz) noexcept {
  const double code = 1.0 / (pwm_frequency_Hz * kPwmPeriodStep_s);
  return code >= 0.5 && code <= kPwmPeriodMaxCode ? static_cast<std::uint16_t>(code + 0.5) : std::uint16_t{0};
}

// The controller's command for one period, controller -> plant. The command computed from
// sample k carries sequence k and is applied by the power stage during period k + 1.
struct InverterCommand {
  std::uint32_t sequence = 0;            // sequence of the sample it was computed from
  std::array<std::uint16_t, 3> duty{};   // high-side on-time fraction, 0 .. 65535 = 0 .. 1
  bool enable = false;                   // false: all gates off (coast, safe torque off)
};

inline constexpr double kDutyFullScale = 65535.0;

// The plant's ground truth, as a test bench's thermocouples and torque flange would report
// it. Published on its own CAN IDs; the controller never reads it.
struct TruthSample {
  std::uint32_t sequence = 0;
  float winding_temp_C = 0.0F;
  float housing_temp_C = 0.0F;
  float magnet_temp_C = 0.0F;
  float rs_ohm = 0.0F;            // phase-to-neutral stator resistance
  float torque_Nm = 0.0F;         // electromagnetic torque (including reluctance torque)
  float speed_rad_s = 0.0F;       // mechanical shaft speed
  float load_torque_Nm = 0.0F;    // torque applied by the load
  float copper_loss_W = 0.0F;
  float iron_loss_W = 0.0F;
};

}  // namespace pmsm::hal
