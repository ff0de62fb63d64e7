# Install rules and the somalab CMake package (find_package(somalab)).
include(CMakePackageConfigHelpers)

# The build tree mirrors an install: <build>/share/somalab links to the
# checkout's resources, so `<build>/soma` finds them beside itself wherever
# the build directory is (framework/core/resources.h), with no source path
# compiled in.
foreach(_dir configs models data ablations viewer)
  file(MAKE_DIRECTORY ${PROJECT_BINARY_DIR}/share/somalab)
  file(CREATE_LINK ${PROJECT_SOURCE_DIR}/${_dir}
       ${PROJECT_BINARY_DIR}/share/somalab/${_dir} SYMBOLIC)
endforeach()

get_property(_soma_libraries GLOBAL PROPERTY SOMA_LIBRARIES)
install(TARGETS soma RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
install(TARGETS ${_soma_libraries}
  EXPORT somalabTargets
  ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR})
install(DIRECTORY ${PROJECT_SOURCE_DIR}/framework/
  DESTINATION ${SOMA_INSTALL_INCLUDEDIR}/framework
  FILES_MATCHING PATTERN "*.h"
  PATTERN "testing" EXCLUDE)
install(FILES
  ${SOMA_BUILD_INFO_DIR}/framework/core/build_info.h
  ${SOMA_BUILD_INFO_DIR}/framework/core/build_git.h
  DESTINATION ${SOMA_INSTALL_INCLUDEDIR}/framework/core)
# The resource root the installed `soma` finds beside itself
# (framework/core/resources.h): bin/../share/somalab.
install(DIRECTORY
  ${PROJECT_SOURCE_DIR}/configs
  ${PROJECT_SOURCE_DIR}/models
  ${PROJECT_SOURCE_DIR}/data
  ${PROJECT_SOURCE_DIR}/ablations
  DESTINATION ${SOMA_INSTALL_DATADIR})
# The page template of `soma view` (built from viewer/src, committed).
install(FILES ${PROJECT_SOURCE_DIR}/viewer/soma_view.html
  DESTINATION ${SOMA_INSTALL_DATADIR}/viewer)

install(EXPORT somalabTargets
  NAMESPACE soma::
  DESTINATION ${SOMA_INSTALL_CMAKEDIR})
configure_package_config_file(
  ${PROJECT_SOURCE_DIR}/cmake/somalabConfig.cmake.in
  ${PROJECT_BINARY_DIR}/somalabConfig.cmake
  INSTALL_DESTINATION ${SOMA_INSTALL_CMAKEDIR}
  PATH_VARS SOMA_INSTALL_DATADIR SOMA_INSTALL_INCLUDEDIR)
write_basic_package_version_file(
  ${PROJECT_BINARY_DIR}/somalabConfigVersion.cmake
  VERSION ${PROJECT_VERSION}
  COMPATIBILITY SameMinorVersion)
install(FILES
  ${PROJECT_BINARY_DIR}/somalabConfig.cmake
  ${PROJECT_BINARY_DIR}/somalabConfigVersion.cmake
  DESTINATION ${SOMA_INSTALL_CMAKEDIR})
