// libFuzzer target: the DBC reader (`pmsm-thermal decode --dbc FILE` reads any file a user
// names). The documented failure is dbc::ParseError naming the line; anything else escaping
// is a crash. A database that parses is used to decode a frame built from the input.
#include <cstdint>
#include <algorithm>
#include <cstring>
#include <string_view>

#include "pmsm/tools/dbc.hpp"

namespace dbc = pmsm::hal::dbc;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    const dbc::Database db = dbc::parse(text);
    for (const dbc::Message& m : db.messages) {
      pmsm::hal::CanFrame f;
      f.id = m.id;
      f.extended = m.extended;
      f.fd = m.fd;
      f.length = static_cast<std::uint8_t>(std::min<std::size_t>(size, f.fd ? 64U : 8U));
      std::memcpy(f.data.data(), data, f.length);
      if (const auto decoded = dbc::decode(db, f)) {
        (void)dbc::format_single_line(*decoded);
      }
    }
  } catch (const dbc::ParseError&) {
  }
  return 0;
}
