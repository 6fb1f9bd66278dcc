// The outcome of an operation on an open/setup path: ok, or an error number with a message
// that names what failed (interface, chip, line, limit) and the errno text.
//
// Used where a caller must decide what to do with a failure (the daemon warns and continues
// when it may not raise its priority; it stops when a configured GPIO chip is missing).
// Building a Status on failure allocates its message, so the hot path never returns one:
// per-period calls report a plain enum (SendResult, ReceiveStatus) or a bool instead.
#pragma once

#include <stdexcept>
#include <string>
#include <utility>

namespace pmsm::hal {

class Status {
 public:
  Status() = default;  // ok

  [[nodiscard]] static Status ok_status() { return {}; }
  [[nodiscard]] static Status error(int error_number, std::string message) {
    Status s;
    s.ok_ = false;
    s.error_number_ = error_number;
    s.message_ = std::move(message);
    return s;
  }

  [[nodiscard]] bool ok() const noexcept { return ok_; }
  explicit operator bool() const noexcept { return ok_; }
  // errno of the failing call (0 when the failure was not a system call's, e.g. a bad argument).
  [[nodiscard]] int error_number() const noexcept { return error_number_; }
  // A full sentence for a log line; empty when ok.
  [[nodiscard]] const std::string& message() const noexcept { return message_; }

 private:
  bool ok_ = true;
  int error_number_ = 0;
  std::string message_;
};

// Thrown by constructors that open OS resources (SocketCanBus, GpiodGateEnableOutput, ...)
// when they cannot: what() is the same kind of sentence as Status::message(). Never thrown
// after construction: every per-period method is noexcept.
class HalError : public std::runtime_error {
 public:
  HalError(int error_number, const std::string& message)
      : std::runtime_error(message), error_number_(error_number) {}
  [[nodiscard]] int error_number() const noexcept { return error_number_; }

 private:
  int error_number_;
};

// "text of errno" (strerror without the thread-safety trap of a static buffer).
[[nodiscard]] std::string errno_text(int error_number);

}  // namespace pmsm::hal
