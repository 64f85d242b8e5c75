// mrft-ident (issue 41): the MRFT relay in ArduCopter's main loop; see MRFT_task.h and docs/sitl.md.
//
// Each tick, after the flight mode has set the attitude and throttle targets: y from the EKF (the
// altitude above home [m], or roll / pitch [rad]), the relay's decision, the delay line (MRFT_DLY
// rounded to whole ticks), then
//   altitude: the throttle, through set_throttle_out(.., PILOT_THR_FILT) as GUIDED's thrust mode does;
//   roll / pitch: the System ID mode's body-rate injection (rate_bf_*_sysid_rads), which the rate
//     controller adds to its target at the next tick (the script opens the axis's rate PID to a unit
//     feed-forward, so the mixer input is the filtered injection).
// The outputs reach the motors at the next tick's motors_output: one tick, the same in every flight.
// Logged every tick as MRFT (the ardupilot-mrft layout of mrft-ident); in SITL also the simulator's
// truth of the same output (Tru: the altitude above home [m], roll or pitch [rad]), so that what the EKF
// adds to the loop can be read from the log (NaN on a vehicle).

#include "MRFT_task.h"

#include <AP_HAL/AP_HAL.h>
#include <AP_AHRS/AP_AHRS.h>
#include <AP_Logger/AP_Logger.h>
#include <AP_Motors/AP_Motors_Class.h>
#include <AP_Scheduler/AP_Scheduler.h>
#include <AC_AttitudeControl/AC_AttitudeControl.h>
#if CONFIG_HAL_BOARD == HAL_BOARD_SITL
#include <SITL/SITL.h>
#endif

MrftTask mrft_task;

static AP_Float *find_float(const char *name)
{
    enum ap_var_type type;
    AP_Param *p = AP_Param::find(name, &type);
    return (p != nullptr && type == AP_PARAM_FLOAT) ? static_cast<AP_Float *>(p) : nullptr;
}

// the script's parameters exist once it has loaded: look them up about once a second until then
bool MrftTask::bind()
{
    if (bound) {
        return true;
    }
    if (bind_wait++ % 400 != 0) {
        return false;
    }
    p_go = find_float("MRFT_GO");
    p_beta = find_float("MRFT_BETA");
    p_h = find_float("MRFT_H");
    p_dly = find_float("MRFT_DLY");
    p_eth = find_float("MRFT_ETH");
    p_bias = find_float("MRFT_BIAS");
    p_run = find_float("MRFT_RUN");
    p_thr_filt = find_float("PILOT_THR_FILT");
    bound = p_go && p_beta && p_h && p_dly && p_eth && p_bias && p_run && p_thr_filt;
    return bound;
}

bool MrftTask::output(float &y) const
{
    const AP_AHRS &ahrs = AP::ahrs();
    if (axis == 1) {
        float down;
        ahrs.get_relative_position_D_home(down);
        y = -down;
    } else {
        y = (axis == 2) ? ahrs.get_roll_rad() : ahrs.get_pitch_rad();
    }
    return isfinite(y);
}

void MrftTask::start(int axis_in)
{
    axis = axis_in;
    float y;
    if (!output(y)) {
        return;
    }
    beta = p_beta->get();
    h = p_h->get();
    bias = p_bias->get();
    sp = (axis == 1) ? y : 0.0f;
    const float rate_hz = AP::scheduler().get_loop_rate_hz();
    const uint16_t ticks = uint16_t(lroundf(MAX(p_dly->get(), 0.0f) * 1.0e-3f * rate_hz));
    relay.reset(beta, p_eth->get());
    delay.reset(ticks, bias);
    dly_s = delay.ticks / rate_hz;
    running = true;
    p_run->set(1);
}

void MrftTask::finish()
{
    // a last sample with the relay off (the command back at its centre) closes the test in the log
    float y = sp;
    output(y);
    write_log(bias, bias, y, 0);
    running = false;
    p_run->set(0);
}

// the simulator's state of the relay's output (SITL builds), else NaN
static float truth(int axis)
{
#if CONFIG_HAL_BOARD == HAL_BOARD_SITL
    const SITL::SIM *sim = AP::sitl();
    if (sim != nullptr) {
        if (axis == 1) {
            return float(sim->state.altitude - sim->state.home.alt * 0.01);
        }
        return radians(float((axis == 2) ? sim->state.rollDeg : sim->state.pitchDeg));
    }
#endif
    return NAN;
}

void MrftTask::write_log(float cmd, float sent, float y, int8_t rel) const
{
    AP::logger().Write("MRFT", "TimeUS,Ax,Cmd,Snt,Out,SP,Rel,B,H,Bias,Dly,Tru", "s---------s-", "F---------0-",
                       "QBffffbfffff", AP_HAL::micros64(), uint8_t(axis), cmd, sent, y, sp, rel, beta, h, bias,
                       dly_s, truth(axis));
}

void MrftTask::update()
{
    if (!bind()) {
        return;
    }
    AP_Motors *motors = AP_Motors::get_singleton();
    AC_AttitudeControl *att = AC_AttitudeControl::get_singleton();
    if (motors == nullptr || att == nullptr) {
        return;
    }
    const int go = int(lroundf(p_go->get()));
    const bool wanted = go >= 1 && go <= 3 && motors->armed();
    if (running && (!wanted || go != axis)) {
        finish();
        return;
    }
    if (!running) {
        if (!wanted) {
            return;
        }
        start(go);
        if (!running) {
            return;
        }
    }
    float y;
    if (!output(y)) {
        finish();
        return;
    }
    const int8_t rel = relay.step(sp - y);
    const float cmd = bias + h * rel;
    const float sent = delay.push(cmd);
    if (axis == 1) {
        att->set_throttle_out(sent, true, p_thr_filt->get());
    } else if (axis == 2) {
        att->rate_bf_roll_sysid_rads(sent);
    } else {
        att->rate_bf_pitch_sysid_rads(sent);
    }
    write_log(cmd, sent, y, rel);
}
