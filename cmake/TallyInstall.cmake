# `cmake --install build [--prefix DIR]`: the binaries (bin/), the image module
# (lib/tally/, installed by common/), the preview page and the examples (share/tally/),
# and the documentation (share/doc/tally/). The binaries find the image module in
# <bin>/../lib/tally (common/image/image_io.hpp); the page is also embedded in
# tally-server; the installed copy is for a reverse proxy that serves it itself.
include(GNUInstallDirs)
foreach(t IN ITEMS tally tally-server tally-worker)
  if(TARGET ${t})
    install(TARGETS ${t} RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
  endif()
endforeach()
install(DIRECTORY ${PROJECT_SOURCE_DIR}/client/preview/ DESTINATION ${CMAKE_INSTALL_DATADIR}/tally/preview)
install(DIRECTORY ${PROJECT_SOURCE_DIR}/examples/ DESTINATION ${CMAKE_INSTALL_DATADIR}/tally/examples)
install(DIRECTORY ${PROJECT_SOURCE_DIR}/docs/ DESTINATION ${CMAKE_INSTALL_DOCDIR} FILES_MATCHING PATTERN "*.md"
  PATTERN "study" EXCLUDE)
install(FILES ${PROJECT_SOURCE_DIR}/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR})
