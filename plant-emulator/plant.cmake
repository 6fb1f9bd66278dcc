# pmsm_plant: the plant-emulator library (motor, inverter, thermal network, sensors).
# Written independently of core/ (DESIGN §3): it links only the shared plain data types and
# the common configuration-schema engine (common/).
add_library(pmsm_plant STATIC
  ${CMAKE_CURRENT_LIST_DIR}/src/config.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/emf.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/thermal.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/plant.cpp)
add_library(pmsm::plant ALIAS pmsm_plant)
pmsm_target_defaults(pmsm_plant)
target_include_directories(pmsm_plant PUBLIC ${CMAKE_CURRENT_LIST_DIR}/include)
# The dev and asan presets build unity batches (CMAKE_UNITY_BUILD); Plant::Impl holds types of
# plant.cpp's anonymous namespace, which GCC's -Wsubobject-linkage rejects once the file is
# included into a batch.
set_source_files_properties(${CMAKE_CURRENT_LIST_DIR}/src/plant.cpp
  PROPERTIES SKIP_UNITY_BUILD_INCLUSION ON)
target_link_libraries(pmsm_plant
  PUBLIC pmsm_messages pmsm_common
  PRIVATE pmsm_math Eigen3::Eigen tomlplusplus::tomlplusplus fmt::fmt)

# pmsm-plant: the plant emulator as a process on a CAN bus (lockstep or real time). The bus
# side (PlantNode) is a library of its own so that tests can run it on the in-process bus.
add_library(pmsm_plant_node STATIC
  ${CMAKE_CURRENT_LIST_DIR}/process/plant_node.cpp
  ${CMAKE_CURRENT_LIST_DIR}/process/log.cpp)
pmsm_target_defaults(pmsm_plant_node)
target_include_directories(pmsm_plant_node PUBLIC ${CMAKE_CURRENT_LIST_DIR})
target_link_libraries(pmsm_plant_node
  PUBLIC pmsm_plant pmsm_protocol pmsm_hal
  PRIVATE spdlog::spdlog)

add_executable(pmsm-plant ${CMAKE_CURRENT_LIST_DIR}/main.cpp)
target_link_libraries(pmsm-plant PRIVATE pmsm_plant_node CLI11::CLI11 spdlog::spdlog fmt::fmt)
pmsm_target_defaults(pmsm-plant)
target_compile_definitions(pmsm-plant PRIVATE PMSM_VERSION="${PROJECT_VERSION}")
# GCC 12 reports a false -Wnull-dereference inside libstdc++'s vector<string> relocation
# as instantiated by CLI11's detail::split (inlined from CLI/StringTools.hpp); keep the
# warning everywhere else.
target_compile_options(pmsm-plant PRIVATE -Wno-null-dereference)
install(TARGETS pmsm-plant RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
install(DIRECTORY ${CMAKE_CURRENT_LIST_DIR}/profiles/ DESTINATION ${CMAKE_INSTALL_DATADIR}/pmsm-thermal/plant-profiles
  FILES_MATCHING PATTERN "*.toml")
