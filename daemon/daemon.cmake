# Shared application utilities (JSON output, ...).
add_library(pmsm_app_common STATIC ${CMAKE_CURRENT_LIST_DIR}/common/json_writer.cpp)
target_include_directories(pmsm_app_common PUBLIC ${CMAKE_CURRENT_LIST_DIR}/common)
pmsm_target_defaults(pmsm_app_common)

# pmsm-thermal: planning, simulation and bus tools.
file(GLOB PMSM_CLI_SOURCES CONFIGURE_DEPENDS ${CMAKE_CURRENT_LIST_DIR}/cli/*.cpp)
add_executable(pmsm-thermal ${PMSM_CLI_SOURCES})
target_link_libraries(pmsm-thermal PRIVATE pmsm::core pmsm_app_common CLI11::CLI11 fmt::fmt)
pmsm_target_defaults(pmsm-thermal)
# GCC 12 reports a false -Wnull-dereference inside libstdc++'s vector<string> relocation
# as instantiated by CLI11's detail::split (inlined from CLI/StringTools.hpp); keep the
# warning everywhere else.
target_compile_options(pmsm-thermal PRIVATE -Wno-null-dereference)
install(TARGETS pmsm-thermal RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
