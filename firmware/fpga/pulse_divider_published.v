// The pulse divider exactly as printed in Yang et al. (2013), §2.2 (kept to reproduce it).
// Only the port names follow pulse_divider.v (compare_reg -> cycle, reset -> reset_n).
//
// DO NOT USE in a design: compare_reg changes every refresh period while a pulse
// period is running; when it drops below compare_count, `compare_count == compare_reg`
// never holds again and the 32-bit counter runs through 2^32 clocks before the next
// edge (86 s at 50 MHz).  jerklab.fpga.published_divider models it clock-exactly;
// tests/test_fpga.py checks this module against that model.
`timescale 1ns/1ps
module pulse_divider_published (
    input  wire        clk,
    input  wire        reset_n,
    input  wire [31:0] cycle,        // the paper's compare_reg
    output reg         clkout,
    output reg  [31:0] count         // the paper's compare_count
);
    wire [31:0] duty;                // occupy proportion
    assign duty = cycle / 2;         // occupy proportion is always 50%

    always @(negedge reset_n or posedge clk) begin
        if (!reset_n) begin
            clkout <= 1'b0;
            count  <= 32'd0;
        end else if (cycle != 32'd0) begin
            if (count == duty) begin
                clkout <= 1'b1;
                count  <= count + 32'd1;
            end else if (count == cycle) begin
                clkout <= 1'b0;
                count  <= 32'd1;
            end else begin
                count  <= count + 32'd1;
            end
        end else begin
            count  <= 32'd0;
            clkout <= 1'b0;
        end
    end
endmodule
