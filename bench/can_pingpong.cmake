# Raw vcan ping-pong: the reference round trip for the HIL figures (DESIGN §9). Plain
# SocketCAN, none of our code, so that it measures the kernel (or UML) and nothing else.
#   scripts/vcan-env -- build/<dir>/bench/can_pingpong --count 20000
add_executable(can_pingpong ${CMAKE_CURRENT_LIST_DIR}/can_pingpong.cpp)
pmsm_target_defaults(can_pingpong)
target_link_libraries(can_pingpong PRIVATE Threads::Threads)
