/* A stand-in for the 12 HAL/RTAPI symbols LinuxCNC's plasmac.so needs, so the component
 * can be loaded into an ordinary process and run one period at a time.
 *
 * Part of dthc-bridge (MIT). Written from the symbols' documented signatures; contains no
 * LinuxCNC code. Pins live in ordinary zeroed memory (a HAL pin nobody connects reads 0),
 * the exported function is kept with its argument, and messages are kept in a small ring
 * instead of printed. Several component copies may register in turn: each reads back the
 * pins and functions it registered by index range.
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_PINS 65536 /* each copy registers ~180; released pins are not reused */
#define MAX_FUNCTS 1024
#define NAME_LEN 64
#define MSG_RING 64
#define MSG_LEN 240

typedef void (*funct_t)(void *arg, long period);

static char (*pin_names)[NAME_LEN];
static int pin_types[MAX_PINS]; /* 1 bit, 2 float, 3 s32: HAL's own type numbers */
static int pin_dirs[MAX_PINS];  /* 16 in, 32 out, 48 io */
static void *pin_data[MAX_PINS];
static int pin_count;
static int first_live; /* pins below it were released: a new run starts the table again */

static funct_t funct_ptrs[MAX_FUNCTS];
static void *funct_args[MAX_FUNCTS];
static int funct_count;

static char messages[MSG_RING][MSG_LEN];
static long message_count;
static int msg_level = 1;

/* --- the 12 symbols ------------------------------------------------------------------- */

int hal_init(const char *name) { (void)name; return 1; }
int hal_exit(int comp_id) { (void)comp_id; return 0; }
int hal_ready(int comp_id) { (void)comp_id; return 0; }

void *hal_malloc(long size) { return calloc(1, (size_t)size); }

int hal_export_funct(const char *name, funct_t funct, void *arg, int uses_fp, int reentrant,
                     int comp_id) {
    (void)name; (void)uses_fp; (void)reentrant; (void)comp_id;
    if (funct_count >= MAX_FUNCTS) return -1;
    funct_ptrs[funct_count] = funct;
    funct_args[funct_count] = arg;
    funct_count++;
    return 0;
}

static int new_pin(int type, int dir, void **data_ptr_addr, size_t size, const char *fmt,
                   va_list ap) {
    if (!pin_names) pin_names = calloc(MAX_PINS, NAME_LEN);
    if (!pin_names || pin_count >= MAX_PINS) return -1;
    void *data = calloc(1, size < 8 ? 8 : size);
    if (!data) return -1;
    vsnprintf(pin_names[pin_count], NAME_LEN, fmt, ap);
    pin_types[pin_count] = type;
    pin_dirs[pin_count] = dir;
    pin_data[pin_count] = data;
    *data_ptr_addr = data;
    pin_count++;
    return 0;
}

int hal_pin_bit_newf(int dir, void **data_ptr_addr, int comp_id, const char *fmt, ...) {
    (void)comp_id;
    va_list ap;
    va_start(ap, fmt);
    int rc = new_pin(1, dir, data_ptr_addr, 1, fmt, ap);
    va_end(ap);
    return rc;
}

int hal_pin_float_newf(int dir, void **data_ptr_addr, int comp_id, const char *fmt, ...) {
    (void)comp_id;
    va_list ap;
    va_start(ap, fmt);
    int rc = new_pin(2, dir, data_ptr_addr, sizeof(double), fmt, ap);
    va_end(ap);
    return rc;
}

int hal_pin_s32_newf(int dir, void **data_ptr_addr, int comp_id, const char *fmt, ...) {
    (void)comp_id;
    va_list ap;
    va_start(ap, fmt);
    int rc = new_pin(3, dir, data_ptr_addr, 4, fmt, ap);
    va_end(ap);
    return rc;
}

int rtapi_get_msg_level(void) { return msg_level; }
int rtapi_set_msg_level(int level) { msg_level = level; return 0; }

void rtapi_print_msg(int level, const char *fmt, ...) {
    if (level > msg_level) return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(messages[message_count % MSG_RING], MSG_LEN, fmt, ap);
    va_end(ap);
    message_count++;
}

int rtapi_snprintf(char *buf, unsigned long size, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    int rc = vsnprintf(buf, size, fmt, ap);
    va_end(ap);
    return rc;
}

/* --- what the host reads -------------------------------------------------------------- */

int shim_pin_count(void) { return pin_count; }
const char *shim_pin_name(int i) { return pin_names[i]; }
int shim_pin_type(int i) { return pin_types[i]; }
int shim_pin_dir(int i) { return pin_dirs[i]; }
void *shim_pin_data(int i) { return pin_data[i]; }
int shim_funct_count(void) { return funct_count; }
long shim_message_count(void) { return message_count; }
const char *shim_message(long i) { return messages[i % MSG_RING]; }

/* A copy is done with: free its pins and forget its function (its code is unloaded next).
 * When every registered pin is released, the tables start again from zero. */
void shim_release(int first_pin, int count, int f) {
    for (int i = first_pin; i < first_pin + count && i < pin_count; i++) {
        free(pin_data[i]);
        pin_data[i] = NULL;
    }
    funct_ptrs[f] = NULL;
    if (first_pin == first_live) first_live = first_pin + count;
    if (first_live >= pin_count) {
        pin_count = first_live = 0;
        while (funct_count > 0 && !funct_ptrs[funct_count - 1]) funct_count--;
    }
}

/* Run function ``f`` ``periods`` times of ``period_ns`` each. */
void shim_run(int f, long period_ns, int periods) {
    funct_t fn = funct_ptrs[f];
    void *arg = funct_args[f];
    for (int k = 0; k < periods; k++) fn(arg, period_ns);
}
