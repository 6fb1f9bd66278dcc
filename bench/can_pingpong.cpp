// Raw SocketCAN ping-pong on a (v)CAN interface: two raw sockets, one per thread. The
// pinger sends a frame and waits for the echo; the echoer answers each ping at once. The
// round trip includes two sends, two wake-ups and two reads, which is what a lockstep
// plant <-> controller exchange costs at least. Prints JSON on stdout:
//   {"iface": "vcan0", "fd": false, "exchanges": N, "median_rtt_us": ..., "p99_rtt_us": ...,
//    "min_rtt_us": ..., "max_rtt_us": ..., "mean_rtt_us": ..., "exchanges_per_s": ...}
//
// Usage: can_pingpong [--iface NAME] [--count N] [--warmup N] [--fd]
// (the interface defaults to $PMSM_CAN_IFACE, then vcan0). Run it under scripts/vcan-env.
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

namespace {

[[noreturn]] void die(const std::string& message) {
  std::fprintf(stderr, "can_pingpong: %s\n", message.c_str());
  std::exit(1);
}

std::int64_t now_ns() {
  timespec ts{};
  ::clock_gettime(CLOCK_MONOTONIC, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + std::int64_t{ts.tv_nsec};
}

class Socket {
 public:
  Socket(const std::string& iface, bool fd, canid_t receive_id) {
    fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
    if (fd_ < 0) {
      die("socket(PF_CAN): " + std::string{std::strerror(errno)} +
          (errno == EAFNOSUPPORT ? " (no CAN in this kernel: run under scripts/vcan-env)" : ""));
    }
    ifreq ifr{};
    if (iface.size() >= sizeof ifr.ifr_name) {
      die("interface name too long: " + iface);
    }
    std::memcpy(ifr.ifr_name, iface.c_str(), iface.size());
    if (::ioctl(fd_, SIOCGIFINDEX, &ifr) != 0) {
      die("no such CAN interface '" + iface + "': " + std::strerror(errno));
    }
    const int ifindex = ifr.ifr_ifindex;
    if (fd) {
      if (::ioctl(fd_, SIOCGIFMTU, &ifr) != 0 || ifr.ifr_mtu != CANFD_MTU) {
        die("'" + iface + "' is not CAN FD capable (MTU must be 72)");
      }
      const int on = 1;
      check(::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on), "CAN_RAW_FD_FRAMES");
    }
    const can_filter filter{receive_id | CAN_EFF_FLAG, CAN_EFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG};
    check(::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FILTER, &filter, sizeof filter), "CAN_RAW_FILTER");
    const timeval timeout{5, 0};  // a lost frame ends the run instead of hanging it
    check(::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout), "SO_RCVTIMEO");
    sockaddr_can addr{};
    addr.can_family = AF_CAN;
    addr.can_ifindex = ifindex;
    check(::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr), "bind");
  }
  ~Socket() { ::close(fd_); }
  Socket(const Socket&) = delete;
  Socket& operator=(const Socket&) = delete;

  void send(const canfd_frame& frame, std::size_t size) const {
    for (;;) {
      const ssize_t n = ::write(fd_, &frame, size);
      if (n == static_cast<ssize_t>(size)) {
        return;
      }
      if (n < 0 && errno == ENOBUFS) {
        std::this_thread::yield();  // device queue full: wait for room as cangen does
        continue;
      }
      die("write: " + std::string{n < 0 ? std::strerror(errno) : "short write"});
    }
  }

  // False on timeout.
  bool receive(canfd_frame& frame, std::size_t expected_size) const {
    const ssize_t n = ::read(fd_, &frame, sizeof frame);
    if (n < 0 && errno == EAGAIN) {  // SO_RCVTIMEO expired (EWOULDBLOCK is the same value)
      return false;
    }
    if (n != static_cast<ssize_t>(expected_size)) {
      die("read returned " + std::to_string(n) + " bytes, expected " + std::to_string(expected_size));
    }
    return true;
  }

 private:
  static void check(int rc, const char* what) {
    if (rc != 0) {
      die(std::string{what} + ": " + std::strerror(errno));
    }
  }
  int fd_ = -1;
};

double percentile_us(const std::vector<std::int64_t>& sorted_ns, double p) {
  const auto index = static_cast<std::size_t>(p * static_cast<double>(sorted_ns.size() - 1) + 0.5);
  return static_cast<double>(sorted_ns[index]) / 1000.0;
}

}  // namespace

int main(int argc, char** argv) {
  const char* env_iface = std::getenv("PMSM_CAN_IFACE");
  std::string iface = env_iface != nullptr && *env_iface != '\0' ? env_iface : "vcan0";
  long count = 10'000;
  long warmup = 200;
  bool fd = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        die(arg + " needs a value");
      }
      return argv[++i];
    };
    if (arg == "--iface") {
      iface = value();
    } else if (arg == "--count") {
      count = std::strtol(value().c_str(), nullptr, 10);
    } else if (arg == "--warmup") {
      warmup = std::strtol(value().c_str(), nullptr, 10);
    } else if (arg == "--fd") {
      fd = true;
    } else {
      die("unknown argument '" + arg + "' (usage: can_pingpong [--iface NAME] [--count N] [--warmup N] [--fd])");
    }
  }
  if (count < 1 || warmup < 0) {
    die("--count must be at least 1 and --warmup not negative");
  }

  // Extended identifiers tagged with the process id, so that runs sharing a native bus
  // do not answer each other.
  const auto tag = (static_cast<canid_t>(::getpid()) & 0xFFFFU) << 12U;
  const canid_t ping_id = tag | 0x1U;
  const canid_t pong_id = tag | 0x2U;
  const std::size_t size = fd ? CANFD_MTU : CAN_MTU;
  const std::uint8_t length = fd ? 64 : 8;
  const long total = warmup + count;

  Socket pinger{iface, fd, pong_id};
  Socket echoer{iface, fd, ping_id};
  std::atomic<bool> echo_failed{false};
  std::thread echo_thread{[&] {
    canfd_frame f{};
    for (long i = 0; i < total; ++i) {
      if (!echoer.receive(f, size)) {
        echo_failed.store(true);
        return;
      }
      f.can_id = pong_id | CAN_EFF_FLAG;
      echoer.send(f, size);
    }
  }};

  std::vector<std::int64_t> rtt_ns;
  rtt_ns.reserve(static_cast<std::size_t>(count));
  canfd_frame ping{};
  ping.can_id = ping_id | CAN_EFF_FLAG;
  ping.len = length;
  if (fd) {
    ping.flags = CANFD_BRS | CANFD_FDF;
  }
  std::int64_t start_ns = 0;
  for (long i = 0; i < total; ++i) {
    if (i == warmup) {
      start_ns = now_ns();
    }
    std::memcpy(ping.data, &i, sizeof i);
    const std::int64_t t0 = now_ns();
    pinger.send(ping, size);
    canfd_frame pong{};
    if (!pinger.receive(pong, size)) {
      echo_thread.join();
      die("no answer to ping " + std::to_string(i) + " within 5 s");
    }
    const std::int64_t t1 = now_ns();
    long echoed = 0;
    std::memcpy(&echoed, pong.data, sizeof echoed);
    if (echoed != i) {
      echo_thread.join();
      die("answer out of order: got " + std::to_string(echoed) + ", expected " + std::to_string(i));
    }
    if (i >= warmup) {
      rtt_ns.push_back(t1 - t0);
    }
  }
  const std::int64_t elapsed_ns = now_ns() - start_ns;
  echo_thread.join();
  if (echo_failed.load()) {
    die("the echo thread timed out");
  }

  std::vector<std::int64_t> sorted = rtt_ns;
  std::sort(sorted.begin(), sorted.end());
  double sum_us = 0.0;
  for (const std::int64_t v : rtt_ns) {
    sum_us += static_cast<double>(v) / 1000.0;
  }
  std::printf(
      "{\"iface\": \"%s\", \"fd\": %s, \"exchanges\": %ld, \"median_rtt_us\": %.1f, \"p99_rtt_us\": %.1f, "
      "\"min_rtt_us\": %.1f, \"max_rtt_us\": %.1f, \"mean_rtt_us\": %.1f, \"exchanges_per_s\": %.0f}\n",
      iface.c_str(), fd ? "true" : "false", count, percentile_us(sorted, 0.5), percentile_us(sorted, 0.99),
      percentile_us(sorted, 0.0), percentile_us(sorted, 1.0), sum_us / static_cast<double>(count),
      static_cast<double>(count) / (static_cast<double>(elapsed_ns) / 1e9));
  return 0;
}
