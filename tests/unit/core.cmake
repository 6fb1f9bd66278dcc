pmsm_add_gtest(core_equations_test LABEL unit
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/core_transforms_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/core_machine_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/core_window_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/core_injection_test.cpp
  LIBS pmsm::core)

pmsm_add_gtest(core_control_test LABEL unit
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/core_modulation_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/core_current_controller_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/core_speed_controller_test.cpp
  LIBS pmsm::core)

pmsm_add_gtest(core_supervisor_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/core_supervisor_test.cpp
  LIBS pmsm::core)
