# Loaded through -DCMAKE_PROJECT_INCLUDE=<this file> by build.sh, only when the
# build uses the ROS 2 PyPI wheels (ros-jazzy-*), never with an apt install.
#
# The wheels' message packages (std_msgs, builtin_interfaces, ...) export their
# <pkg>__rosidl_generator_py target with the wheel builder's Python include
# directories baked in (/opt/python/cp311-cp311/include/python3.11 and that
# interpreter's numpy/_core/include). Those paths do not exist here, and CMake
# refuses to generate ("Imported target ... includes non-existent path").
# At the end of the configure step, every imported target's include
# directories that do not exist are replaced by the include directories of the
# Python that rosidl_generator_py found (Python3_INCLUDE_DIRS and
# Python3_NumPy_INCLUDE_DIRS), which are the ones those paths stood for.
# Nothing outside the build tree is changed. Needs CMake >= 3.21 (the
# IMPORTED_TARGETS directory property; cmake_language(DEFER) is 3.19).

if(CMAKE_VERSION VERSION_LESS 3.21)
  message(FATAL_ERROR "pypi_wheel_fixups.cmake needs CMake >= 3.21, this is ${CMAKE_VERSION}")
endif()

function(_hill_muscle_fix_wheel_include_dirs)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(_target IN LISTS _targets)
    get_target_property(_dirs "${_target}" INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_fixed)
    set(_changed FALSE)
    foreach(_dir IN LISTS _dirs)
      if(_dir MATCHES "^\\$<" OR EXISTS "${_dir}")
        list(APPEND _fixed "${_dir}")
      elseif(_dir MATCHES "/numpy/")
        list(APPEND _fixed ${Python3_NumPy_INCLUDE_DIRS})
        set(_changed TRUE)
      elseif(_dir MATCHES "/include/python3")
        list(APPEND _fixed ${Python3_INCLUDE_DIRS})
        set(_changed TRUE)
      else()
        # any other missing directory: dropped (nothing can be found in it)
        set(_changed TRUE)
      endif()
    endforeach()
    if(_changed)
      list(REMOVE_DUPLICATES _fixed)
      set_target_properties("${_target}" PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_fixed}")
      message(STATUS "PyPI wheel fix-up: ${_target} include directories -> ${_fixed}")
    endif()
  endforeach()
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _hill_muscle_fix_wheel_include_dirs)
