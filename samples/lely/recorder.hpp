// recorder.hpp - what record.cpp and boot/record_boot.cpp share: the clock, the
// event log on stderr, the candump -L recorder on the main bus, the connector that
// plugs a device's stub bus into the main bus, and the slave application (see the
// comment at the top of record.cpp). Included once by each recorder.
//
// Part of nmtcheck (MIT, see pyproject.toml). It contains no Lely code; it only
// includes the headers of, and links against, an installed lely-core (Apache-2.0).

#pragma once

#include <lely/coapp/master.hpp>
#include <lely/coapp/slave.hpp>
#include <lely/ev/loop.hpp>
#include <lely/io2/posix/poll.hpp>
#include <lely/io2/sys/clock.hpp>
#include <lely/io2/sys/io.hpp>
#include <lely/io2/sys/timer.hpp>
#include <lely/io2/vcan.hpp>

#include <chrono>
#include <cinttypes>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

using namespace lely;
using namespace std::chrono_literals;
using canopen::NmtCommand;
using canopen::NmtState;

namespace {

constexpr double kEpoch = 1700000000.0;
std::chrono::nanoseconds g_start{0};

std::chrono::nanoseconds
mono_now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return std::chrono::seconds(ts.tv_sec) + std::chrono::nanoseconds(ts.tv_nsec);
}

double
rel_now() {
  return std::chrono::duration<double>(mono_now() - g_start).count();
}

void
event(const char* fmt, ...) __attribute__((format(printf, 1, 2)));

void
event(const char* fmt, ...) {
  std::fprintf(stderr, "# t=%.6f ", rel_now());
  va_list ap;
  va_start(ap, fmt);
  std::vfprintf(stderr, fmt, ap);
  va_end(ap);
  std::fputc('\n', stderr);
}

const char*
st_name(NmtState st) {
  switch (st) {
    case NmtState::BOOTUP:
      return "BOOTUP";
    case NmtState::STOP:
      return "STOPPED";
    case NmtState::START:
      return "OPERATIONAL";
    case NmtState::RESET_NODE:
      return "RESET_NODE";
    case NmtState::RESET_COMM:
      return "RESET_COMM";
    case NmtState::PREOP:
      return "PRE-OPERATIONAL";
    default:
      return "?";
  }
}

const char*
cs_name(NmtCommand cs) {
  switch (cs) {
    case NmtCommand::START:
      return "START";
    case NmtCommand::STOP:
      return "STOP";
    case NmtCommand::ENTER_PREOP:
      return "ENTER_PREOP";
    case NmtCommand::RESET_NODE:
      return "RESET_NODE";
    case NmtCommand::RESET_COMM:
      return "RESET_COMM";
    default:
      return "?";
  }
}

// The receive-only channel on the main bus that writes candump -L lines.
class Recorder {
 public:
  Recorder(io::Context& ctx, ev_exec_t* exec, io::VirtualCanController& bus,
           FILE* out, const char* iface)
      : chan_(ctx, exec, 65536),
        out_(out),
        iface_(iface),
        read_(&msg_, nullptr, &ts_, exec, [this](int result, std::error_code ec) {
          OnRead(result, ec);
        }) {
    chan_.open(bus);
    chan_.submit_read(read_);
  }

  uint64_t frames() const { return frames_; }

 private:
  void
  OnRead(int result, std::error_code ec) {
    if (result == 1) {
      Write();
    } else if (result == -1 && ec != std::errc::operation_canceled) {
      std::fprintf(stderr, "recorder: read error: %s\n", ec.message().c_str());
    }
    if (result != -1 || ec != std::errc::operation_canceled)
      chan_.submit_read(read_);
  }

  void
  Write() {
    ++frames_;
    double t = kEpoch + std::chrono::duration<double>(ts_ - g_start).count();
    char data[64] = "";
    if (msg_.flags & CAN_FLAG_RTR) {
      // candump -L: "ID#R", with the DLC after R if it is not 0.
      if (msg_.len)
        std::snprintf(data, sizeof(data), "R%u", msg_.len);
      else
        std::snprintf(data, sizeof(data), "R");
    } else {
      for (int i = 0; i < msg_.len && i < 8; i++)
        std::snprintf(data + 2 * i, 3, "%02X", msg_.data[i]);
    }
    if (msg_.flags & CAN_FLAG_IDE)
      std::fprintf(out_, "(%.6f) %s %08" PRIX32 "#%s\n", t, iface_, msg_.id, data);
    else
      std::fprintf(out_, "(%.6f) %s %03" PRIX32 "#%s\n", t, iface_, msg_.id, data);
  }

  io::VirtualCanChannel chan_;
  FILE* out_;
  const char* iface_;
  can_msg msg_ = CAN_MSG_INIT;
  std::chrono::nanoseconds ts_{0};
  io::CanChannelRead read_;
  uint64_t frames_{0};
};

// A device's stub bus plus the connector that joins it to the main bus.
class Connector {
  int node_;

 public:
  Connector(io::Context& ctx, ev_exec_t* exec, io::VirtualCanController& bus,
            int node)
      : node_(node),
        stub_(io::clock_monotonic),
        dev(ctx, exec),
        stub_side_(ctx, exec),
        bus_side_(ctx, exec),
        up_read_(&up_msg_, nullptr, nullptr, exec,
                 [this](int r, std::error_code ec) { OnUp(r, ec); }),
        down_read_(&down_msg_, nullptr, nullptr, exec,
                   [this](int r, std::error_code ec) { OnDown(r, ec); }) {
    dev.open(stub_);
    stub_side_.open(stub_);
    bus_side_.open(bus);
    stub_side_.submit_read(up_read_);
    bus_side_.submit_read(down_read_);
  }

  void
  set_plugged(bool plugged) {
    plugged_ = plugged;
  }
  bool plugged() const { return plugged_; }

  // The device's own channel (on the stub bus).
  io::VirtualCanController stub_;
  io::VirtualCanChannel dev;

  uint64_t sent{0};         // frames of the device put on the main bus
  uint64_t sent_lost{0};    // frames of the device dropped while unplugged
  uint64_t received{0};     // frames from the main bus (all, plugged or not)
  uint64_t delivered{0};    // of those, delivered to the device
  uint64_t errors{0};       // write errors (should stay 0)
  // Called for every frame of the device that reaches the main bus.
  std::function<void(const can_msg&)> on_sent;

 private:
  void
  OnUp(int r, std::error_code ec) {
    if (r == 1) {
      if (plugged_) {
        std::error_code wec;
        bus_side_.write(up_msg_, 0, wec);
        if (wec) {
          ++errors;
          std::fprintf(stderr, "node %d: write to bus failed: %s\n", node_,
                       wec.message().c_str());
        } else {
          ++sent;
          if (on_sent) on_sent(up_msg_);
        }
      } else {
        ++sent_lost;
      }
    }
    if (r != -1 || ec != std::errc::operation_canceled)
      stub_side_.submit_read(up_read_);
  }

  void
  OnDown(int r, std::error_code ec) {
    if (r == 1) {
      ++received;
      if (plugged_) {
        std::error_code wec;
        stub_side_.write(down_msg_, 0, wec);
        if (wec) {
          ++errors;
          std::fprintf(stderr, "node %d: write to stub failed: %s\n", node_,
                       wec.message().c_str());
        } else {
          ++delivered;
        }
      }
    }
    if (r != -1 || ec != std::errc::operation_canceled)
      bus_side_.submit_read(down_read_);
  }

  bool plugged_{true};
  io::VirtualCanChannel stub_side_;
  io::VirtualCanChannel bus_side_;
  can_msg up_msg_ = CAN_MSG_INIT;
  can_msg down_msg_ = CAN_MSG_INIT;
  io::CanChannelRead up_read_;
  io::CanChannelRead down_read_;
};

class Slave : public canopen::BasicSlave {
 public:
  Slave(ev_exec_t* exec, io::TimerBase& timer, io::CanChannelBase& chan,
        const std::string& dcf, int node)
      : BasicSlave(exec, timer, chan, dcf, "", node), node_(node) {}

  // A firmware that accepts an SDO download of 1017h but keeps producing no
  // heartbeat (the value stays 0).
  void
  IgnoreHeartbeatWrites() {
    int node = node_;
    OnWrite<uint16_t>(0x1017, 0,
                      [node](uint16_t, uint8_t, uint16_t& new_val,
                             uint16_t old_val) -> std::error_code {
                        event("node %d: application ignores 1017h = %u", node,
                              new_val);
                        new_val = old_val;
                        return {};
                      });
  }

  // Application: count and send TPDO1 (2000h:00, event-driven). Lely only
  // sends the PDO when the node is OPERATIONAL and TPDO1 is valid.
  void
  Tick() {
    uint32_t v = (*this)[0x2000][0];
    (*this)[0x2000][0] = v + 1;
    (*this)[0x2000][0].SetEvent();
  }

  // Application writes its own 1017h (local SDO download, no bus traffic).
  void
  SetHeartbeat(uint16_t ms) {
    Write<uint16_t>(0x1017, 0, ms);
  }

 private:
  void
  OnCommand(NmtCommand cs) noexcept override {
    event("node %d: NMT command %s", node_, cs_name(cs));
  }
  void
  OnHeartbeat(uint8_t id, bool occurred) noexcept override {
    event("node %d: heartbeat event for node %d %s", node_, id,
          occurred ? "occurred" : "resolved");
  }
  void
  OnLifeGuarding(bool occurred) noexcept override {
    event("node %d: life guarding event %s", node_,
          occurred ? "occurred" : "resolved");
  }

  // The node-ID (Device::id() takes the device lock, which the stack already
  // holds while it calls these callbacks).
  int node_;
};

}  // namespace
