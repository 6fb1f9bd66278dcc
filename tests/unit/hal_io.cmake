# Unit tests of pmsm_hal (the OS-facing half of hal/): they need no CAN and no GPIO chip.
# ctest names them hal_io_unit_tests.<Suite>.<Test>, so `ctest -R hal` selects them.
pmsm_add_gtest(hal_io_unit_tests LABEL unit
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/hal_spsc_ring_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/hal_sim_bus_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/hal_gpio_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/hal_socketcan_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/hal_rt_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/hal_journal_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/hal_loop_test.cpp
  LIBS pmsm::hal)
