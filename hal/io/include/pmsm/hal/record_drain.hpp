// Fixed-size records from the RT thread to a normal thread: the RT side pushes into an
// SpscRing (never blocks; a full ring drops and counts), a drain thread pops them every
// `interval` and hands each to a handler (publishing frames, logging with spdlog). The
// handler runs on the drain thread only, so it may allocate, lock and log.
//
//   SpscRing<Record, 1024> ring;
//   RecordDrain<Record, 1024> drain(ring, [](const Record& r) { log(r); }, 5ms);
//   ... RT thread: ring.try_push(r);
//   drain.stop();   // drains what is left, then joins
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>

#include "pmsm/hal/spsc_ring.hpp"

namespace pmsm::hal {

template <typename T, std::size_t N>
class RecordDrain {
 public:
  using Handler = std::function<void(const T&)>;

  RecordDrain(SpscRing<T, N>& ring, Handler handler, std::chrono::nanoseconds interval,
              std::function<void()> after_batch = {})
      : ring_(ring), handler_(std::move(handler)), after_batch_(std::move(after_batch)), interval_(interval),
        thread_([this] { run(); }) {}
  ~RecordDrain() { stop(); }
  RecordDrain(const RecordDrain&) = delete;
  RecordDrain& operator=(const RecordDrain&) = delete;

  // Stops the thread after draining everything pushed so far. Idempotent.
  void stop() {
    {
      const std::lock_guard lock(mutex_);
      stopping_ = true;
    }
    wake_.notify_all();
    if (thread_.joinable()) {
      thread_.join();
    }
  }

  // Records handed to the handler so far (any thread).
  [[nodiscard]] std::uint64_t drained() const noexcept { return drained_.load(std::memory_order_relaxed); }

 private:
  void drain_all() {
    T record;
    while (ring_.try_pop(record)) {
      handler_(record);
      drained_.store(drained_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
    }
    if (after_batch_) {
      after_batch_();
    }
  }

  void run() {
    std::unique_lock lock(mutex_);
    for (;;) {
      const bool stopping = wake_.wait_for(lock, interval_, [this] { return stopping_; });
      lock.unlock();
      drain_all();
      lock.lock();
      if (stopping) {
        return;
      }
    }
  }

  SpscRing<T, N>& ring_;
  Handler handler_;
  std::function<void()> after_batch_;
  std::chrono::nanoseconds interval_;
  std::atomic<std::uint64_t> drained_{0};
  std::mutex mutex_;
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread thread_;  // last: starts after everything it uses
};

}  // namespace pmsm::hal
