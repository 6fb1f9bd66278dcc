# Keeps the dependency arrows of docs/architecture.md true at the level of #include lines:
#   core <- drive <- daemon, tools;  hal/protocol <- drive, daemon, plant-emulator, tools;
#   hal/io <- daemon, plant-emulator's process, tools;  common <- drive, plant-emulator, tools.
# Run as `cmake -DROOT=<source dir> -P cmake/CheckArchitecture.cmake` (ctest:
# architecture_dependencies). Prints every offending line and fails.
if(NOT ROOT)
  message(FATAL_ERROR "pass -DROOT=<source dir>")
endif()

# The headers of each part, by the name they are included with.
set(protocol_headers can_frame.hpp codec.hpp crc8.hpp messages.hpp protocol.hpp protocol_filters.hpp)
set(io_headers can_bus.hpp gpio.hpp rt.hpp sim_bus.hpp socketcan.hpp spsc_ring.hpp status.hpp unique_fd.hpp
    wait.hpp signals.hpp counters.hpp record_drain.hpp realtime_value.hpp)

set(violations "")

# check(<folder> <description> <regex of forbidden include targets>)
function(check folder description forbidden)
  file(GLOB_RECURSE sources "${ROOT}/${folder}/*.hpp" "${ROOT}/${folder}/*.cpp" "${ROOT}/${folder}/*.h")
  foreach(source IN LISTS sources)
    file(STRINGS "${source}" lines REGEX "^[ \t]*#[ \t]*include[ \t]*[\"<]")
    foreach(line IN LISTS lines)
      string(REGEX REPLACE "^[ \t]*#[ \t]*include[ \t]*[\"<]([^\">]+)[\">].*$" "\\1" target "${line}")
      if(target MATCHES "${forbidden}")
        file(RELATIVE_PATH rel "${ROOT}" "${source}")
        set(violations "${violations}\n  ${rel}: #include \"${target}\" (${description})" PARENT_SCOPE)
        set(violations "${violations}\n  ${rel}: #include \"${target}\" (${description})")
      endif()
    endforeach()
  endforeach()
endfunction()

list(JOIN io_headers "|" io_alt)
string(REPLACE "." "\\." io_alt "${io_alt}")
list(JOIN protocol_headers "|" protocol_alt)
string(REPLACE "." "\\." protocol_alt "${protocol_alt}")

# core/: the paper and the control laws; Eigen and the standard library only.
check(core "core/ includes only core/, Eigen and the standard library"
      "^pmsm/(hal|plant|tools|drive|common)/|^(toml|spdlog|fmt|CLI|gpiod|systemd|linux|sys|unistd|poll|fcntl)|config_schema|config_types|toml_fwd|controller_config")
# hal/protocol: pure; nothing of the OS side, core, drive or the tools.
check(hal/protocol "hal/protocol is pure: no OS, core, drive or tool headers"
      "^pmsm/(core|plant|tools)/|^pmsm/hal/(${io_alt})$|^(linux|sys|unistd|poll|fcntl|spdlog|toml)")
# hal/io: the OS boundary; plain message types only from the protocol.
check(hal/io "hal/io depends on the plain message types only"
      "^pmsm/(core|plant|tools)/|^pmsm/hal/(codec|protocol|protocol_filters|crc8)\\.hpp$")
# common/: the schema engine; nothing of the project.
check(common "common/ depends on nothing of the project" "^pmsm/")
# plant-emulator/: independent physics (DESIGN §3); never core/, drive/ or tools/.
check(plant-emulator "the plant never includes core/, drive/ or tools/ (a shared wrong sign would pass every test)"
      "^pmsm/(core|tools)/|controller_config|sensor_frontend|drive_node|calibration_file|supervisor")
# drive/: core + protocol + common; no buses, threads or logging, no plant, no tools (files
# for the stored calibration and thermal state are its only I/O).
check(drive "drive/ uses core, hal/protocol and common only; no bus, RT or logging"
      "^pmsm/(plant|tools)/|^pmsm/hal/(${io_alt})$|^(linux/|sys/socket|poll|spdlog|thread|mutex)")

if(violations)
  message(FATAL_ERROR "dependency arrows broken (docs/architecture.md):${violations}")
endif()
message(STATUS "architecture: every include follows the dependency arrows")
