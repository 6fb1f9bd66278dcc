// In-process CAN bus for fast tests: a SimBus and any number of endpoints (CanBus) on it,
// following SocketCAN's rules (see can_bus.hpp): no echo to the sender, filters, error
// masks, FD only between FD endpoints. Each endpoint has a bounded receive queue, allocated
// when it connects; a frame that finds it full is dropped and counted in the receiver's
// rx_overflow, as the kernel does when a socket's receive buffer is full.
//
// Thread-safe: a plant thread and a controller thread may each drive their own endpoint,
// and a test thread may flip the bus state at the same time. Locks are taken (this is a
// test double, not the RT path of a real drive).
#pragma once

#include <cstddef>
#include <memory>

#include "pmsm/hal/can_bus.hpp"

namespace pmsm::hal {

struct SimBusConfig {
  bool fd_capable = true;  // false: like an interface with MTU 16, FD endpoints are refused
};

struct SimEndpointConfig {
  bool fd = false;                    // receive and send CAN FD frames
  std::size_t queue_capacity = 256;   // frames held before overflow
};

class SimBus {
 public:
  explicit SimBus(SimBusConfig config = {});
  ~SimBus();
  SimBus(const SimBus&) = delete;
  SimBus& operator=(const SimBus&) = delete;

  // A new endpoint. Throws HalError if an FD endpoint is asked of a bus that is not
  // fd_capable, or the capacity is 0. Endpoints may outlive the SimBus object.
  [[nodiscard]] std::unique_ptr<CanBus> connect(SimEndpointConfig config = {});

  // Test hooks: take the interface down (sends and receives report kInterfaceDown,
  // queued frames are discarded), bring it back up.
  void set_interface_up(bool up);
  // Delivers an error frame (CanFrame::error set, id = CanErrorClass bits) to every
  // endpoint whose error mask selects it, as a controller's driver would.
  void inject_error_frame(const CanFrame& error_frame);

  // Frames sent on the bus so far (by all endpoints).
  [[nodiscard]] std::size_t frames_sent() const;

  struct Core;

 private:
  std::shared_ptr<Core> core_;
};

// An error frame as a controller reports a state change, for tests: bus-off,
// error-passive (rx and tx), warning, back to error-active, or restarted.
[[nodiscard]] CanFrame make_error_frame(CanBusState state);

}  // namespace pmsm::hal
