/* A stand-in libk4abt for tests without the Azure Kinect Body Tracking SDK.
 *
 * Exports the SDK functions app/nodes/backends/_k4abt.py binds, with the signatures of
 * k4abt.h (Body Tracking SDK 1.1.x) and the type layouts of k4abttypes.h / k4atypes.h,
 * written out here so the test needs no SDK headers. They are copied from the SDK's
 * headers, not from the binding (sources: docs/backbone.md, "What was checked against
 * the SDKs"); the test compares sizes and field offsets with the binding's ctypes
 * structures, so a binding layout that drifts from the SDK's fails.
 * Built with -DSTUB_K4ABT_1_0 it stands for Body Tracking SDK 1.0.x instead: the 1.0
 * configuration {orientation, processing_mode, gpu_device_id} and no
 * k4abt_frame_get_system_timestamp_nsec, which the binding must refuse to load. Bodies are scripted per capture
 * handle with stub_script(); joint values follow a formula the test checks:
 *   position (mm) = (id * 100 + j, -10 * j, pelvis_z + j), orientation (w,x,y,z) =
 *   (1, 0.5 * j, 0, 0), confidence = j % 4 (NONE, LOW, MEDIUM, HIGH cycling).
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* k4atypes.h */
typedef enum { K4A_RESULT_SUCCEEDED = 0, K4A_RESULT_FAILED } k4a_result_t;
typedef enum { K4A_WAIT_RESULT_SUCCEEDED = 0, K4A_WAIT_RESULT_FAILED, K4A_WAIT_RESULT_TIMEOUT } k4a_wait_result_t;
typedef union { struct { float x, y, z; } xyz; float v[3]; } k4a_float3_t;
typedef struct _k4a_calibration_t k4a_calibration_t; /* opaque here: only a pointer is passed */
typedef struct _k4a_capture_t *k4a_capture_t;
typedef struct _k4a_image_t *k4a_image_t;

/* k4abttypes.h */
#define K4ABT_JOINT_COUNT 32
typedef struct _k4abt_tracker_t *k4abt_tracker_t;
typedef struct _k4abt_frame_t *k4abt_frame_t;
typedef enum { K4ABT_SENSOR_ORIENTATION_DEFAULT = 0, K4ABT_SENSOR_ORIENTATION_CLOCKWISE90,
               K4ABT_SENSOR_ORIENTATION_COUNTERCLOCKWISE90,
               K4ABT_SENSOR_ORIENTATION_FLIP180 } k4abt_sensor_orientation_t;
typedef enum { K4ABT_TRACKER_PROCESSING_MODE_GPU = 0, K4ABT_TRACKER_PROCESSING_MODE_CPU,
               K4ABT_TRACKER_PROCESSING_MODE_GPU_CUDA, K4ABT_TRACKER_PROCESSING_MODE_GPU_TENSORRT,
               K4ABT_TRACKER_PROCESSING_MODE_GPU_DIRECTML } k4abt_tracker_processing_mode_t;
typedef struct _k4abt_tracker_configuration_t {
    k4abt_sensor_orientation_t sensor_orientation;
    k4abt_tracker_processing_mode_t processing_mode;
    int32_t gpu_device_id;
#ifndef STUB_K4ABT_1_0
    const char *model_path; /* new in 1.1.0 */
#endif
} k4abt_tracker_configuration_t;
typedef union { struct { float w, x, y, z; } wxyz; float v[4]; } k4a_quaternion_t;
typedef enum { K4ABT_JOINT_CONFIDENCE_NONE = 0, K4ABT_JOINT_CONFIDENCE_LOW = 1,
               K4ABT_JOINT_CONFIDENCE_MEDIUM = 2, K4ABT_JOINT_CONFIDENCE_HIGH = 3,
               K4ABT_JOINT_CONFIDENCE_LEVELS_COUNT = 4 } k4abt_joint_confidence_level_t;
typedef struct _k4abt_joint_t {
    k4a_float3_t position;
    k4a_quaternion_t orientation;
    k4abt_joint_confidence_level_t confidence_level;
} k4abt_joint_t;
typedef struct _k4abt_skeleton_t { k4abt_joint_t joints[K4ABT_JOINT_COUNT]; } k4abt_skeleton_t;
typedef struct _k4abt_body_t { uint32_t id; k4abt_skeleton_t skeleton; } k4abt_body_t;

#define MAX_BODIES 4
#define STUB_QUEUE_CAPACITY 3
#define MAX_SCRIPT 64
typedef struct {
    uint64_t capture;
    uint32_t n;
    uint32_t ids[MAX_BODIES];
    float pelvis_z[MAX_BODIES];
    uint64_t ts;
} scripted_t;

static scripted_t script[MAX_SCRIPT];
static int n_script = 0;
static scripted_t *queue[MAX_SCRIPT];
static int q_head = 0, q_tail = 0;
static int tracker_alive = 0, fail_gpu = 0, released = 0;
static k4abt_tracker_configuration_t last_config;
static const void *last_calibration = NULL;
static char last_model_path[256];
static int images_released = 0;
static int pop_delays = 0;

/* ---- test controls (not SDK functions) */
void stub_reset(int fail_gpu_modes) {
    n_script = 0; q_head = q_tail = 0; tracker_alive = 0; released = 0;
    fail_gpu = fail_gpu_modes; memset(&last_config, 0, sizeof last_config);
    last_calibration = NULL; last_model_path[0] = 0; images_released = 0;
    pop_delays = 0;
}
int stub_script(uint64_t capture, uint32_t n, const uint32_t *ids, const float *pelvis_z, uint64_t ts) {
    if (n_script >= MAX_SCRIPT || n > MAX_BODIES) return -1;
    scripted_t *s = &script[n_script++];
    s->capture = capture; s->n = n; s->ts = ts;
    for (uint32_t i = 0; i < n; i++) { s->ids[i] = ids[i]; s->pelvis_z[i] = pelvis_z[i]; }
    return 0;
}
int stub_last_config(int32_t *orientation, int32_t *mode, int32_t *gpu, const void **calibration) {
    *orientation = last_config.sensor_orientation; *mode = last_config.processing_mode;
    *gpu = last_config.gpu_device_id; *calibration = last_calibration;
    return tracker_alive;
}
/* the next n pops time out although a result is queued (a slow tracker) */
void stub_delay_pops(int n) { pop_delays = n; }
const char *stub_last_model_path(void) { return last_model_path; }
int stub_released(void) { return released; }
size_t stub_sizeof_skeleton(void) { return sizeof(k4abt_skeleton_t); }
size_t stub_sizeof_config(void) { return sizeof(k4abt_tracker_configuration_t); }
size_t stub_sizeof_joint(void) { return sizeof(k4abt_joint_t); }
size_t stub_sizeof_body(void) { return sizeof(k4abt_body_t); }
/* offsets the binding's ctypes structures must reproduce, -1 for an unknown name */
long stub_offsetof(const char *field) {
    static const struct { const char *name; size_t off; } table[] = {
        {"joint.position", offsetof(k4abt_joint_t, position)},
        {"joint.orientation", offsetof(k4abt_joint_t, orientation)},
        {"joint.orientation.w", offsetof(k4abt_joint_t, orientation.wxyz.w)},
        {"joint.orientation.z", offsetof(k4abt_joint_t, orientation.wxyz.z)},
        {"joint.confidence_level", offsetof(k4abt_joint_t, confidence_level)},
        {"config.sensor_orientation", offsetof(k4abt_tracker_configuration_t, sensor_orientation)},
        {"config.processing_mode", offsetof(k4abt_tracker_configuration_t, processing_mode)},
        {"config.gpu_device_id", offsetof(k4abt_tracker_configuration_t, gpu_device_id)},
#ifndef STUB_K4ABT_1_0
        {"config.model_path", offsetof(k4abt_tracker_configuration_t, model_path)},
#endif
    };
    for (size_t i = 0; i < sizeof table / sizeof table[0]; i++)
        if (strcmp(table[i].name, field) == 0) return (long)table[i].off;
    return -1;
}

/* ---- k4abt.h */
k4a_result_t k4abt_tracker_create(const k4a_calibration_t *sensor_calibration,
                                  k4abt_tracker_configuration_t config,
                                  k4abt_tracker_t *tracker_handle) {
    if (sensor_calibration == NULL || tracker_handle == NULL || tracker_alive) return K4A_RESULT_FAILED;
    last_config = config; last_calibration = sensor_calibration;
#ifndef STUB_K4ABT_1_0
    if (config.model_path) { strncpy(last_model_path, config.model_path, 255); last_model_path[255] = 0; }
#endif
    if (fail_gpu && config.processing_mode != K4ABT_TRACKER_PROCESSING_MODE_CPU) return K4A_RESULT_FAILED;
    tracker_alive = 1;
    *tracker_handle = (k4abt_tracker_t)&tracker_alive;
    return K4A_RESULT_SUCCEEDED;
}
void k4abt_tracker_destroy(k4abt_tracker_t tracker_handle) { (void)tracker_handle; tracker_alive = 0; }
void k4abt_tracker_shutdown(k4abt_tracker_t tracker_handle) { (void)tracker_handle; }
k4a_wait_result_t k4abt_tracker_enqueue_capture(k4abt_tracker_t tracker_handle,
                                                k4a_capture_t sensor_capture_handle,
                                                int32_t timeout_in_ms) {
    (void)timeout_in_ms;
    if (tracker_handle == NULL || !tracker_alive) return K4A_WAIT_RESULT_FAILED;
    /* the real queue: "the SDK will buffer at least three body frames worth of data
     * before stopping new capture being queued" (k4abt_tracker_pop_result reference) */
    if (q_tail - q_head >= STUB_QUEUE_CAPACITY) return K4A_WAIT_RESULT_TIMEOUT;
    for (int i = 0; i < n_script; i++)
        if (script[i].capture == (uint64_t)(uintptr_t)sensor_capture_handle) {
            queue[q_tail++ % MAX_SCRIPT] = &script[i];
            return K4A_WAIT_RESULT_SUCCEEDED;
        }
    return K4A_WAIT_RESULT_FAILED; /* like a capture without depth */
}
k4a_wait_result_t k4abt_tracker_pop_result(k4abt_tracker_t tracker_handle,
                                           k4abt_frame_t *body_frame_handle,
                                           int32_t timeout_in_ms) {
    (void)timeout_in_ms;
    if (tracker_handle == NULL || !tracker_alive) return K4A_WAIT_RESULT_FAILED;
    if (q_head == q_tail) return K4A_WAIT_RESULT_TIMEOUT;
    if (pop_delays > 0) { pop_delays--; return K4A_WAIT_RESULT_TIMEOUT; }
    *body_frame_handle = (k4abt_frame_t)queue[q_head++ % MAX_SCRIPT];
    return K4A_WAIT_RESULT_SUCCEEDED;
}
void k4abt_frame_release(k4abt_frame_t body_frame_handle) { if (body_frame_handle) released++; }
uint32_t k4abt_frame_get_num_bodies(k4abt_frame_t f) { return f ? ((scripted_t *)f)->n : 0; }
uint32_t k4abt_frame_get_body_id(k4abt_frame_t f, uint32_t index) {
    if (!f || index >= ((scripted_t *)f)->n) return 0xFFFFFFFF; /* K4ABT_INVALID_BODY_ID */
    return ((scripted_t *)f)->ids[index];
}
uint64_t k4abt_frame_get_device_timestamp_usec(k4abt_frame_t f) { return f ? ((scripted_t *)f)->ts : 0; }
#ifndef STUB_K4ABT_1_0
/* new in 1.1.0 (absent from the 1.0.1 API reference): the binding's 1.1 marker */
uint64_t k4abt_frame_get_system_timestamp_nsec(k4abt_frame_t f) { return f ? 1000 * ((scripted_t *)f)->ts : 0; }
#endif
k4a_result_t k4abt_frame_get_body_skeleton(k4abt_frame_t f, uint32_t index, k4abt_skeleton_t *skeleton) {
    scripted_t *s = (scripted_t *)f;
    if (!s || !skeleton || index >= s->n) return K4A_RESULT_FAILED;
    for (int j = 0; j < K4ABT_JOINT_COUNT; j++) {
        k4abt_joint_t *jt = &skeleton->joints[j];
        jt->position.xyz.x = (float)(s->ids[index] * 100 + j);
        jt->position.xyz.y = -10.0f * j;
        jt->position.xyz.z = s->pelvis_z[index] + j;
        jt->orientation.wxyz.w = 1.0f; jt->orientation.wxyz.x = 0.5f * j;
        jt->orientation.wxyz.y = 0.0f; jt->orientation.wxyz.z = 0.0f;
        jt->confidence_level = (k4abt_joint_confidence_level_t)(j % 4);
    }
    return K4A_RESULT_SUCCEEDED;
}

/* ---- body index map: an 8 x 6 CUSTOM8 image, stride 10, column c holds body index c
 * for c < number of bodies, else K4ABT_BODY_INDEX_MAP_BACKGROUND (255); a NULL image for
 * frames scripted with pelvis_z[0] < 0 (a tracker without a map). The k4a_image_*
 * functions below stand in for libk4a's (k4a.h, sensor SDK 1.4). */
typedef struct { int w, h, stride; uint8_t buf[60]; } stub_image_t;
int stub_images_released(void) { return images_released; }
k4a_image_t k4abt_frame_get_body_index_map(k4abt_frame_t f) {
    scripted_t *s = (scripted_t *)f;
    if (!s || (s->n > 0 && s->pelvis_z[0] < 0)) return NULL;
    stub_image_t *im = calloc(1, sizeof *im);
    im->w = 8; im->h = 6; im->stride = 10;
    for (int r = 0; r < im->h; r++)
        for (int c = 0; c < im->stride; c++)
            im->buf[r * im->stride + c] = (uint8_t)((uint32_t)c < s->n ? c : (c < im->w ? 255 : 77));
    return (k4a_image_t)im;
}
uint8_t *k4a_image_get_buffer(k4a_image_t image) { return image ? ((stub_image_t *)image)->buf : NULL; }
int k4a_image_get_width_pixels(k4a_image_t image) { return image ? ((stub_image_t *)image)->w : 0; }
int k4a_image_get_height_pixels(k4a_image_t image) { return image ? ((stub_image_t *)image)->h : 0; }
int k4a_image_get_stride_bytes(k4a_image_t image) { return image ? ((stub_image_t *)image)->stride : 0; }
void k4a_image_release(k4a_image_t image) { if (image) { images_released++; free(image); } }
