// In-process CAN bus (see sim_bus.hpp).
#include "pmsm/hal/sim_bus.hpp"

#include <linux/can.h>
#include <linux/can/error.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <optional>
#include <vector>

namespace pmsm::hal {

namespace {

class SimEndpoint;

std::int64_t realtime_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

}  // namespace

struct SimBus::Core {
  explicit Core(SimBusConfig c) : config(c) {}
  SimBusConfig config;
  mutable std::mutex mutex;            // guards endpoints, up, frames_sent
  std::vector<SimEndpoint*> endpoints;
  bool up = true;
  std::size_t frames_sent = 0;

  void deliver(const SimEndpoint* sender, const CanFrame& frame);
};

namespace {

class SimEndpoint final : public CanBus {
 public:
  SimEndpoint(std::shared_ptr<SimBus::Core> core, SimEndpointConfig config)
      : core_(std::move(core)), config_(config), queue_(config.queue_capacity) {
    const std::lock_guard bus_lock{core_->mutex};
    core_->endpoints.push_back(this);
  }

  ~SimEndpoint() override {
    const std::lock_guard bus_lock{core_->mutex};
    auto& v = core_->endpoints;
    v.erase(std::remove(v.begin(), v.end(), this), v.end());
  }

  SimEndpoint(const SimEndpoint&) = delete;
  SimEndpoint& operator=(const SimEndpoint&) = delete;

  Status set_filters(std::span<const CanFilter> filters) override {
    const std::lock_guard lock{mutex_};
    filters_.emplace(filters.begin(), filters.end());
    return {};
  }

  Status set_error_mask(std::uint32_t error_classes) override {
    const std::lock_guard lock{mutex_};
    error_mask_ = error_classes & CAN_ERR_MASK;
    return {};
  }

  Status reopen() override {
    const std::lock_guard lock{mutex_};
    count_ = 0;
    head_ = 0;
    state_.store(CanBusState::kErrorActive);
    return {};
  }

  [[nodiscard]] CanBusCounters counters() const noexcept override {
    const std::lock_guard lock{mutex_};
    return counters_;
  }
  [[nodiscard]] CanBusState state() const noexcept override { return state_.load(); }
  [[nodiscard]] bool interface_up() const noexcept override {
    const std::lock_guard lock{core_->mutex};
    return core_->up;
  }
  [[nodiscard]] bool fd_enabled() const noexcept override { return config_.fd; }

  // Called by the core with the bus lock held (never the endpoint's own frames).
  void offer(const CanFrame& frame, std::int64_t timestamp_ns) {
    {
      const std::lock_guard lock{mutex_};
      if (frame.error) {
        if ((frame.id & error_mask_) == 0U) {
          return;
        }
      } else {
        if (frame.fd && !config_.fd) {
          return;  // the kernel gives FD frames only to sockets that enabled them
        }
        if (filters_.has_value() && !passes_filters(frame, *filters_)) {
          return;
        }
      }
      if (count_ == queue_.size()) {
        ++counters_.rx_overflow;
        return;
      }
      queue_[(head_ + count_) % queue_.size()] = ReceivedFrame{frame, timestamp_ns, false, timestamp_ns};
      ++count_;
    }
    ready_.notify_one();
  }

  // The interface went down or up: when down, queued frames are lost and waiting readers
  // wake up. Called with the bus lock held.
  void link_changed(bool up) {
    {
      const std::lock_guard lock{mutex_};
      link_up_ = up;
      if (!up) {
        count_ = 0;
      }
    }
    ready_.notify_all();
  }

 protected:
  SendResult do_send(const CanFrame& frame, std::chrono::nanoseconds /*max_wait*/) noexcept override {
    // The simulated bus never runs out of transmit room, so there is nothing to wait for.
    if (!is_sendable(frame, config_.fd)) {
      const std::lock_guard lock{mutex_};
      ++counters_.tx_errors;
      return SendResult::kInvalidFrame;
    }
    {
      const std::lock_guard bus_lock{core_->mutex};
      if (!core_->up) {
        const std::lock_guard lock{mutex_};
        ++counters_.tx_errors;
        ++counters_.interface_down_events;
        return SendResult::kInterfaceDown;
      }
      core_->deliver(this, frame);
    }
    const std::lock_guard lock{mutex_};
    ++counters_.tx_frames;
    return SendResult::kOk;
  }

  ReceiveStatus do_receive(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept override {
    // The wait as this call's own clock saw it (ReceivedFrame::waited_ns), so that a caller's
    // timing from it runs in the in-process tests as on SocketCAN.
    const auto called = std::chrono::steady_clock::now();
    std::unique_lock lock{mutex_};
    const auto ready = [&] { return count_ > 0 || !link_up_; };
    if (timeout.count() < 0) {
      ready_.wait(lock, ready);
    } else if (!ready_.wait_for(lock, timeout, ready)) {
      return ReceiveStatus::kTimeout;
    }
    if (count_ == 0) {
      ++counters_.interface_down_events;
      return ReceiveStatus::kInterfaceDown;
    }
    out = queue_[head_];
    out.waited_ns = timeout.count() < 0 ? -1 : std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - called).count();
    head_ = (head_ + 1) % queue_.size();
    --count_;
    if (out.frame.error) {
      ++counters_.error_frames;
      const CanBusState before = state_.load();
      const CanBusState after = state_after_error_frame(out.frame, before);
      if (after == CanBusState::kBusOff && before != CanBusState::kBusOff) {
        ++counters_.bus_off_events;
      }
      state_.store(after);
    } else {
      ++counters_.rx_frames;
    }
    return ReceiveStatus::kFrame;
  }

 private:
  // Lock order: the bus mutex before an endpoint's mutex.
  std::shared_ptr<SimBus::Core> core_;
  SimEndpointConfig config_;
  mutable std::mutex mutex_;  // guards everything below except state_
  std::condition_variable ready_;
  std::vector<ReceivedFrame> queue_;
  std::size_t head_ = 0;
  std::size_t count_ = 0;
  std::optional<std::vector<CanFilter>> filters_;
  std::uint32_t error_mask_ = 0;
  CanBusCounters counters_;
  bool link_up_ = true;  // the bus's state, copied here so that waiting readers see it
  std::atomic<CanBusState> state_{CanBusState::kErrorActive};
};

}  // namespace

void SimBus::Core::deliver(const SimEndpoint* sender, const CanFrame& frame) {
  const std::int64_t now_ns = realtime_ns();
  ++frames_sent;
  for (SimEndpoint* endpoint : endpoints) {
    if (endpoint != sender) {
      endpoint->offer(frame, now_ns);
    }
  }
}

SimBus::SimBus(SimBusConfig config) : core_(std::make_shared<Core>(config)) {}

SimBus::~SimBus() = default;

std::unique_ptr<CanBus> SimBus::connect(SimEndpointConfig config) {
  if (config.queue_capacity == 0) {
    throw HalError(EINVAL, "simulated CAN endpoint needs a queue capacity of at least 1 frame");
  }
  if (config.fd && !core_->config.fd_capable) {
    throw HalError(EPROTONOSUPPORT,
                   "CAN FD requested on the simulated bus but it is classic CAN only (fd_capable = false)");
  }
  auto endpoint = std::make_unique<SimEndpoint>(core_, config);
  {
    const std::lock_guard lock{core_->mutex};
    endpoint->link_changed(core_->up);
  }
  return endpoint;
}

void SimBus::set_interface_up(bool up) {
  const std::lock_guard lock{core_->mutex};
  core_->up = up;
  for (SimEndpoint* endpoint : core_->endpoints) {
    endpoint->link_changed(up);
  }
}

void SimBus::inject_error_frame(const CanFrame& error_frame) {
  CanFrame frame = error_frame;
  frame.error = true;
  frame.fd = false;
  const std::lock_guard lock{core_->mutex};
  core_->deliver(nullptr, frame);
}

std::size_t SimBus::frames_sent() const {
  const std::lock_guard lock{core_->mutex};
  return core_->frames_sent;
}

CanFrame make_error_frame(CanBusState state) {
  CanFrame frame;
  frame.error = true;
  frame.length = CAN_ERR_DLC;
  switch (state) {
    case CanBusState::kBusOff:
      frame.id = CAN_ERR_BUSOFF;
      break;
    case CanBusState::kErrorPassive:
      frame.id = CAN_ERR_CRTL;
      frame.data[1] = CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE;
      break;
    case CanBusState::kErrorWarning:
      frame.id = CAN_ERR_CRTL;
      frame.data[1] = CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING;
      break;
    case CanBusState::kErrorActive:
      frame.id = CAN_ERR_CRTL;
      frame.data[1] = CAN_ERR_CRTL_ACTIVE;
      break;
  }
  return frame;
}

}  // namespace pmsm::hal
