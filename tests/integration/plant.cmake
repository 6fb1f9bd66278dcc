# Plant emulator in a closed loop, in-process (a minimal test-local current controller that
# sees only sensor codes).
pmsm_add_gtest(plant_integration_test LABEL integration
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/plant_closed_loop_test.cpp
  LIBS pmsm::plant)
