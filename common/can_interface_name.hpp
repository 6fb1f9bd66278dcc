// The kernel's rule for a network interface's name, and this project's (no control
// characters), for configuration checks and for the candump parser (decode and monitor print
// a log's interface back). Header only, standard library only.
#pragma once

#include <cctype>
#include <string>
#include <string_view>

#include "printable.hpp"

namespace pmsm::common {

// Why `name` cannot name a network interface, or "" when it can: the kernel's rule
// (dev_valid_name: 1 to 15 characters, not "." or "..", no '/', ':' or white space) and no
// control characters (which the kernel takes, but a NUL ends a name early and an escape
// reaches a terminal). The name is quoted escaped (printable_excerpt).
[[nodiscard]] inline std::string can_interface_name_problem(std::string_view name) {
  if (name.empty()) {
    return "an interface name is 1 to 15 characters, got an empty one";
  }
  if (name.size() > 15) {
    // (Its first characters only: a 10 MB value was echoed whole into the journal.)
    return "an interface name is 1 to 15 characters, got " + std::to_string(name.size()) + " in '" +
           printable_excerpt(name, name.size() > 40 ? 32 : 40) + "'";
  }
  if (name == "." || name == "..") {
    std::string problem{"'"};  // (appended: GCC 12's false -Wrestrict on "literal" + string&&)
    problem += name;
    problem += "' is not an interface name";
    return problem;
  }
  for (const char ch : name) {
    if (ch == '/' || ch == ':' || std::isspace(static_cast<unsigned char>(ch)) != 0) {
      return "an interface name has no '/', ':' or white space, got '" + printable_excerpt(name) + "'";
    }
    if (std::iscntrl(static_cast<unsigned char>(ch)) != 0) {
      return "an interface name has no control characters (a NUL would end it early), got '" +
             printable_excerpt(name) + "'";
    }
  }
  return {};
}

}  // namespace pmsm::common
