# Plant-emulator unit tests (fast; the whole set runs in a few seconds).
pmsm_add_gtest(plant_unit_test LABEL unit
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/plant_config_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/plant_physics_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/plant_thermal_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/plant_inverter_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/plant_mechanics_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/plant_sensors_test.cpp
  LIBS pmsm::plant Eigen3::Eigen)

# Own binary: it replaces malloc and its family (tests/support/alloc_counter) to count allocations.
pmsm_add_gtest(plant_alloc_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/plant_alloc_test.cpp
  LIBS pmsm::plant pmsm_test_alloc_counter)
