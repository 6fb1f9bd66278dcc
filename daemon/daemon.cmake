# Shared application utilities (JSON output, ...).
add_library(pmsm_app_common STATIC ${CMAKE_CURRENT_LIST_DIR}/common/json_writer.cpp)
target_include_directories(pmsm_app_common PUBLIC ${CMAKE_CURRENT_LIST_DIR}/common)
target_link_libraries(pmsm_app_common PUBLIC tomlplusplus::tomlplusplus)
pmsm_target_defaults(pmsm_app_common)

# The drive's wiring shared by pmsm-thermald and the simulator: the controller's
# configuration and the sensor front end.
file(GLOB PMSM_DRIVE_SOURCES CONFIGURE_DEPENDS ${CMAKE_CURRENT_LIST_DIR}/drive/*.cpp)
add_library(pmsm_drive STATIC ${PMSM_DRIVE_SOURCES})
target_include_directories(pmsm_drive PUBLIC ${CMAKE_CURRENT_LIST_DIR}/drive)
target_link_libraries(pmsm_drive PUBLIC pmsm::core pmsm_messages pmsm_app_common tomlplusplus::tomlplusplus PRIVATE fmt::fmt)
pmsm_target_defaults(pmsm_drive)

# The in-process closed loop (scenario runner): controller + plant library.
file(GLOB PMSM_SIM_SOURCES CONFIGURE_DEPENDS ${CMAKE_CURRENT_LIST_DIR}/sim/*.cpp)
add_library(pmsm_sim STATIC ${PMSM_SIM_SOURCES})
target_include_directories(pmsm_sim PUBLIC ${CMAKE_CURRENT_LIST_DIR}/sim)
target_link_libraries(pmsm_sim PUBLIC pmsm_drive pmsm::plant PRIVATE fmt::fmt)
pmsm_target_defaults(pmsm_sim)

# pmsm-thermal: planning, simulation and bus tools.
file(GLOB PMSM_CLI_SOURCES CONFIGURE_DEPENDS ${CMAKE_CURRENT_LIST_DIR}/cli/*.cpp)
add_executable(pmsm-thermal ${PMSM_CLI_SOURCES})
target_link_libraries(pmsm-thermal PRIVATE pmsm::core pmsm_app_common pmsm_sim pmsm::protocol CLI11::CLI11 fmt::fmt)
pmsm_target_defaults(pmsm-thermal)
# GCC 12 reports a false -Wnull-dereference inside libstdc++'s vector<string> relocation
# as instantiated by CLI11's detail::split (inlined from CLI/StringTools.hpp); keep the
# warning everywhere else.
target_compile_options(pmsm-thermal PRIVATE -Wno-null-dereference)
install(TARGETS pmsm-thermal RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
# The DBC, where `pmsm-thermal decode` looks for it by default (share/pmsm-thermal/).
install(FILES ${PROJECT_SOURCE_DIR}/can/pmsm-thermal.dbc DESTINATION ${CMAKE_INSTALL_DATADIR}/pmsm-thermal)
