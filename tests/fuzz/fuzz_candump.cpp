// libFuzzer target: one line of candump output (`pmsm-thermal decode`, `monitor --log`), as
// anyone may pipe into the tools. Checks beyond ASan + UBSan: parse_line never throws; a
// parsed record printed as a candump -L line parses back to the same frame; decode_line with
// the project's DBC never throws.
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string_view>

#include "pmsm/tools/candump.hpp"
#include "pmsm/tools/dbc.hpp"

namespace candump = pmsm::hal::candump;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const pmsm::hal::dbc::Database db = pmsm::hal::dbc::load(PMSM_DBC_PATH);
  const std::string_view line(reinterpret_cast<const char*>(data), size);
  const candump::ParseResult r = candump::parse_line(line);
  if (r.ok()) {
    if (!r.error.empty()) std::abort();
    const candump::ParseResult again = candump::parse_line(candump::to_log_line(*r.record));
    if (!again.ok()) std::abort();  // our own -L line must parse
    const auto& a = r.record->frame;
    const auto& b = again.record->frame;
    if (a.id != b.id || a.extended != b.extended || a.fd != b.fd || a.length != b.length || a.error != b.error ||
        std::memcmp(a.data.data(), b.data.data(), a.length) != 0) {
      std::abort();
    }
  } else if (r.error.empty()) {
    std::abort();  // a rejection always says why
  }
  (void)candump::decode_line(db, line);
  return 0;
}
