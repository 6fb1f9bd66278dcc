// The HIL latency tool's three small processes (bench/hil-latency.sh runs them):
//
//   can_latency echo    --id ID              answers every frame ID with frame ID+1
//   can_latency ping    --id ID --count N    sends ID, waits for ID+1, sends the next at once
//   can_latency observe --id ID --count N    kernel receive time of each frame ID; prints the
//                                            intervals between them as JSON with a histogram
//
// The floor is echo + ping: two minimal processes, one read and one write each per exchange.
// The same observer then watches SENSOR_SAMPLE while pmsm-plant (lockstep) and pmsm-thermald
// run: the interval between two samples is one whole lockstep period (sample -> daemon ->
// command -> plant -> next sample), as the interval between two pings is one exchange. The
// observer reads the kernel's receive timestamps (SO_TIMESTAMPNS), so no process in the loop
// reads a clock for the measurement, and both figures come from one method in one boot.
//
// Frames: CAN FD, the ping 24 bytes and the answer 12 (SENSOR_SAMPLE's and INVERTER_COMMAND's
// lengths). IDs are extended by default (29-bit, tagged so that runs on a shared native bus
// do not meet); --standard takes ID as an 11-bit identifier (e.g. SENSOR_SAMPLE 0x021).
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace {

[[noreturn]] void die(const std::string& message) {
  std::fprintf(stderr, "can_latency: %s\n", message.c_str());
  std::exit(1);
}

void check(int rc, const char* what) {
  if (rc != 0) {
    die(std::string{what} + ": " + std::strerror(errno));
  }
}

struct Options {
  std::string role;
  std::string iface = "vcan0";
  canid_t id = 0;
  bool standard = false;
  long count = 10000;
  long warmup = 200;
  int timeout_s = 10;
};

// A raw CAN FD socket that receives only `id` (exact match).
int open_socket(const Options& o, canid_t receive_id, bool timestamps) {
  const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) {
    die("socket(PF_CAN): " + std::string{std::strerror(errno)} +
        (errno == EAFNOSUPPORT ? " (no CAN in this kernel: run under scripts/vcan-env)" : ""));
  }
  ifreq ifr{};
  if (o.iface.size() >= sizeof ifr.ifr_name) {
    die("interface name too long: " + o.iface);
  }
  std::memcpy(ifr.ifr_name, o.iface.c_str(), o.iface.size());
  if (::ioctl(fd, SIOCGIFINDEX, &ifr) != 0) {
    die("no such CAN interface '" + o.iface + "': " + std::strerror(errno));
  }
  const int ifindex = ifr.ifr_ifindex;
  const int on = 1;
  check(::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on), "CAN_RAW_FD_FRAMES (is the MTU 72?)");
  const can_filter filter = o.standard
                                ? can_filter{receive_id, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG}
                                : can_filter{receive_id | CAN_EFF_FLAG, CAN_EFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG};
  check(::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, &filter, sizeof filter), "CAN_RAW_FILTER");
  if (timestamps) {
    check(::setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on), "SO_TIMESTAMPNS");
    const int buffer = 16 << 20;  // the observer must never drop a frame
    // Beyond net.core.rmem_max with CAP_NET_ADMIN (as candump -r); capped there otherwise.
    if (::setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &buffer, sizeof buffer) != 0) {
      (void)::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &buffer, sizeof buffer);
    }
  }
  const timeval timeout{o.timeout_s, 0};  // a lost frame ends the run instead of hanging it
  check(::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout), "SO_RCVTIMEO");
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifindex;
  check(::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr), "bind");
  return fd;
}

canid_t wire_id(const Options& o, canid_t id) { return o.standard ? id : (id | CAN_EFF_FLAG); }

void send_frame(int fd, canid_t id, std::uint8_t length, long sequence) {
  canfd_frame f{};
  f.can_id = id;
  f.len = length;
  f.flags = CANFD_FDF;
  std::memcpy(f.data, &sequence, sizeof sequence);
  for (;;) {
    const ssize_t n = ::write(fd, &f, CANFD_MTU);
    if (n == CANFD_MTU) {
      return;
    }
    if (n < 0 && errno == ENOBUFS) {
      continue;  // device queue full: try again, as cangen does
    }
    die("write: " + std::string{n < 0 ? std::strerror(errno) : "short write"});
  }
}

// False on timeout.
bool receive_frame(int fd, canfd_frame& f) {
  const ssize_t n = ::read(fd, &f, sizeof f);
  if (n < 0 && errno == EAGAIN) {
    return false;
  }
  if (n != CANFD_MTU) {
    die("read returned " + std::to_string(n) + " bytes (not a CAN FD frame)");
  }
  return true;
}

int run_echo(const Options& o) {
  const int fd = open_socket(o, o.id, false);
  std::printf("ready\n");
  std::fflush(stdout);
  canfd_frame f{};
  for (long k = 0; receive_frame(fd, f); ++k) {
    long sequence = 0;
    std::memcpy(&sequence, f.data, sizeof sequence);
    send_frame(fd, wire_id(o, o.id + 1), 12, sequence);
    if (sequence < 0) {
      return 0;  // the pinger's last word
    }
  }
  return 0;  // nobody pinged for timeout_s: done
}

int run_ping(const Options& o) {
  const int fd = open_socket(o, o.id + 1, false);
  canfd_frame f{};
  for (long k = 0; k < o.warmup + o.count; ++k) {
    send_frame(fd, wire_id(o, o.id), 24, k);
    if (!receive_frame(fd, f)) {
      die("no answer to ping " + std::to_string(k) + " within " + std::to_string(o.timeout_s) + " s");
    }
  }
  send_frame(fd, wire_id(o, o.id), 24, -1);  // ends the echo
  return 0;
}

double percentile(const std::vector<double>& sorted, double p) {
  const auto index = static_cast<std::size_t>(std::lround(p * static_cast<double>(sorted.size() - 1)));
  return sorted[index];
}

int run_observe(const Options& o) {
  const int fd = open_socket(o, o.id, true);
  std::printf("ready\n");
  std::fflush(stdout);
  std::vector<double> interval_us;
  interval_us.reserve(static_cast<std::size_t>(o.count));
  std::int64_t previous_ns = -1;
  long seen = 0;
  while (seen < o.warmup + o.count + 1) {
    canfd_frame f{};
    iovec iov{&f, sizeof f};
    alignas(cmsghdr) char control[CMSG_SPACE(sizeof(timespec))];
    msghdr msg{};
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    const ssize_t n = ::recvmsg(fd, &msg, 0);
    if (n < 0 && errno == EAGAIN) {
      die("observed " + std::to_string(seen) + " frames, then none for " + std::to_string(o.timeout_s) + " s");
    }
    if (n < 0) {
      die(std::string("recvmsg: ") + std::strerror(errno));
    }
    std::int64_t t_ns = -1;
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
      if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS) {
        timespec ts{};
        std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
        t_ns = std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
      }
    }
    if (t_ns < 0) {
      die("no kernel timestamp on a received frame");
    }
    if (seen > o.warmup && previous_ns >= 0) {
      interval_us.push_back(static_cast<double>(t_ns - previous_ns) / 1000.0);
    }
    previous_ns = t_ns;
    ++seen;
  }
  std::vector<double> sorted = interval_us;
  if (sorted.empty()) {
    die("no interval observed");
  }
  std::sort(sorted.begin(), sorted.end());
  // Histogram: 20 bins from the minimum to the 99.9th percentile, one more for the rest.
  const double lo = sorted.front();
  const double hi = std::max(percentile(sorted, 0.999), lo + 1.0);
  constexpr int kBins = 20;
  std::vector<long> bins(kBins + 1, 0);
  for (const double v : sorted) {
    const int b = v >= hi ? kBins : static_cast<int>((v - lo) / (hi - lo) * kBins);
    ++bins[static_cast<std::size_t>(std::min(b, kBins))];
  }
  std::string histogram;
  for (int b = 0; b <= kBins; ++b) {
    const double from = lo + (hi - lo) * b / kBins;
    histogram += (b > 0 ? ", " : "") + std::string("[") + std::to_string(from) + ", " + std::to_string(bins[static_cast<std::size_t>(b)]) + "]";
  }
  std::printf(
      "{\"intervals\": %zu, \"min_us\": %.1f, \"median_us\": %.1f, \"p99_us\": %.1f, \"p999_us\": %.1f, "
      "\"max_us\": %.1f, \"histogram_from_us_count\": [%s]}\n",
      sorted.size(), sorted.front(), percentile(sorted, 0.5), percentile(sorted, 0.99), percentile(sorted, 0.999),
      sorted.back(), histogram.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  const char* env_iface = std::getenv("PMSM_CAN_IFACE");
  if (env_iface != nullptr && *env_iface != '\0') {
    o.iface = env_iface;
  }
  const std::string usage =
      "usage: can_latency echo|ping|observe --id ID [--standard] [--iface NAME] [--count N] [--warmup N] [--timeout-s S]";
  if (argc < 2) {
    die(usage);
  }
  o.role = argv[1];
  bool have_id = false;
  for (int i = 2; i < argc; ++i) {
    const std::string arg = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        die(arg + " needs a value");
      }
      return argv[++i];
    };
    char* end = nullptr;
    if (arg == "--id") {
      const std::string v = value();
      o.id = static_cast<canid_t>(std::strtoul(v.c_str(), &end, 0));
      have_id = end != v.c_str() && *end == '\0';
    } else if (arg == "--standard") {
      o.standard = true;
    } else if (arg == "--iface") {
      o.iface = value();
    } else if (arg == "--count") {
      o.count = std::strtol(value().c_str(), nullptr, 10);
    } else if (arg == "--warmup") {
      o.warmup = std::strtol(value().c_str(), nullptr, 10);
    } else if (arg == "--timeout-s") {
      o.timeout_s = static_cast<int>(std::strtol(value().c_str(), nullptr, 10));
    } else {
      die("unknown argument '" + arg + "'; " + usage);
    }
  }
  if (!have_id || o.count < 10 || o.warmup < 0 || o.timeout_s < 1 ||
      o.id > (o.standard ? CAN_SFF_MASK - 1 : CAN_EFF_MASK - 1)) {
    die("bad --id, --count (>= 10), --warmup or --timeout-s; " + usage);
  }
  if (o.role == "echo") return run_echo(o);
  if (o.role == "ping") return run_ping(o);
  if (o.role == "observe") return run_observe(o);
  die(usage);
}
