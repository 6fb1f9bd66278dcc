# pmsm_plant: the plant-emulator library (motor, inverter, thermal network, sensors).
# Written independently of core/ (DESIGN §3): it links only the shared plain data types.
add_library(pmsm_plant STATIC
  ${CMAKE_CURRENT_LIST_DIR}/src/config.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/emf.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/thermal.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/plant.cpp)
add_library(pmsm::plant ALIAS pmsm_plant)
pmsm_target_defaults(pmsm_plant)
target_include_directories(pmsm_plant PUBLIC ${CMAKE_CURRENT_LIST_DIR}/include)
target_link_libraries(pmsm_plant
  PUBLIC pmsm_messages
  PRIVATE Eigen3::Eigen tomlplusplus::tomlplusplus fmt::fmt)
