# pmsm_hal: the operating-system half of hal/ (SocketCAN, in-process bus, GPIO, real-time
# helpers). Included from hal/CMakeLists.txt; independent of pmsm_protocol.
add_library(pmsm_hal STATIC
  ${CMAKE_CURRENT_LIST_DIR}/src/io/can_bus.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/io/socketcan.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/io/sim_bus.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/io/gpio.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/io/gpio_gpiod.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/io/rt.cpp)
add_library(pmsm::hal ALIAS pmsm_hal)
pmsm_target_defaults(pmsm_hal)
target_include_directories(pmsm_hal PRIVATE ${CMAKE_CURRENT_LIST_DIR}/src/io)
target_link_libraries(pmsm_hal
  PUBLIC pmsm_messages Threads::Threads
  PRIVATE PkgConfig::GPIOD)
