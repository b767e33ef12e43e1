#include "common/lighting/embree_device.hpp"

#include <fmt/format.h>

#include <stdexcept>

namespace tally {

namespace {

thread_local std::optional<std::string> t_error;

const char* error_name(RTCError code) {
  switch (code) {
    case RTC_ERROR_NONE: return "none";
    case RTC_ERROR_UNKNOWN: return "unknown";
    case RTC_ERROR_INVALID_ARGUMENT: return "invalid argument";
    case RTC_ERROR_INVALID_OPERATION: return "invalid operation";
    case RTC_ERROR_OUT_OF_MEMORY: return "out of memory";
    case RTC_ERROR_UNSUPPORTED_CPU: return "unsupported CPU";
    case RTC_ERROR_CANCELLED: return "cancelled";
  }
  return "?";
}

void on_error(void*, RTCError code, const char* message) {
  if (!t_error) t_error = fmt::format("Embree error ({}): {}", error_name(code), message ? message : "");
}

struct DeviceHolder {
  RTCDevice device = nullptr;
  DeviceHolder() {
    device = rtcNewDevice(nullptr);
    if (device == nullptr) {
      throw std::runtime_error(fmt::format("cannot create the Embree device: {}",
                                           error_name(rtcGetDeviceError(nullptr))));
    }
    rtcSetDeviceErrorFunction(device, on_error, nullptr);
  }
  ~DeviceHolder() {
    if (device) rtcReleaseDevice(device);
  }
  DeviceHolder(const DeviceHolder&) = delete;
  DeviceHolder& operator=(const DeviceHolder&) = delete;
};

}  // namespace

RTCDevice embree_device() {
  static DeviceHolder holder;
  return holder.device;
}

std::optional<std::string> take_embree_error() {
  std::optional<std::string> e;
  e.swap(t_error);
  return e;
}

}  // namespace tally
