// mrft-ident (issue 41): the MRFT relay as a task of ArduCopter's main loop (a FAST_TASK run right
// after update_flight_mode, at the loop rate, in the simulation's lockstep). Started and stopped by
// scripts/sitl/mrft_relay.lua through its MRFT_* parameters; see docs/sitl.md.
#pragma once

#include <AP_Param/AP_Param.h>
#include "MRFT_relay.h"

class MrftTask {
public:
    void update();

private:
    bool bind();
    void start(int axis_in);
    void finish();
    bool output(float &y) const;
    void write_log(float cmd, float sent, float y, int8_t rel) const;

    AP_Float *p_go, *p_beta, *p_h, *p_dly, *p_eth, *p_bias, *p_run, *p_thr_filt;
    bool bound = false;
    uint16_t bind_wait = 0;
    bool running = false;
    int axis = 0;
    float beta = 0, h = 0, bias = 0, sp = 0, dly_s = 0;
    mrft::Relay relay;
    mrft::DelayLine<128> delay;
};

extern MrftTask mrft_task;
