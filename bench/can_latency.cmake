# The HIL latency tool's processes (bench/hil-latency.sh): a minimal ping-pong between two
# processes and an observer with kernel receive timestamps. Plain SocketCAN, none of our code.
add_executable(can_latency ${CMAKE_CURRENT_LIST_DIR}/can_latency.cpp)
pmsm_target_defaults(can_latency)
