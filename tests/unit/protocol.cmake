# The CAN protocol: CRC-8, codec round trips and rejections, receive filters, DBC agreement
# (committed DBC and docs equal to the generated ones), candump parsing. All label unit.
pmsm_add_gtest(protocol_codec_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/protocol_codec_test.cpp
  LIBS pmsm::protocol_tools)

pmsm_add_gtest(protocol_dbc_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/protocol_dbc_test.cpp
  LIBS pmsm::protocol_tools)

pmsm_add_gtest(protocol_candump_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/protocol_candump_test.cpp
  LIBS pmsm::protocol_tools)
