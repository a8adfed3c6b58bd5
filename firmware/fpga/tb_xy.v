// Yang et al.'s x–y stand (their §4, Fig. 9): two scurve_gen + pulse_divider pairs on one clock
// and one reset, each with its own parameters (X_*, Y_*), driven from one synchronized plan
// (jerklab.fpga.yang_axes computes the parameters; jerklab.fpga.simulate_verilog_xy runs this).
// Prints, at the negedge after a change,
//   SX|SY <m> <n> <speed> <freq> <cycle>   for every refresh tick of the x / y generator
//   EX|EY <posedge index> <clkout>         for every output edge of the x / y divider
// Posedges are numbered from 1 (the first after reset).  Runs P_END posedges.  +vcd=<file> dumps a VCD.
`timescale 1ns/1ps
module tb_xy;
    parameter [31:0] X_V = 32'd20000, X_N = 32'd2500, X_CRUISE = 32'd5000, X_A_NUM = 32'd1,
                     X_B_DEN = 32'd625, X_K = 32'd20, X_F_CLK = 32'd50000000, X_R = 32'd10000,
                     X_N_MIN = 32'd300;
    parameter [31:0] Y_V = 32'd20000, Y_N = 32'd2500, Y_CRUISE = 32'd5000, Y_A_NUM = 32'd1,
                     Y_B_DEN = 32'd625, Y_K = 32'd20, Y_F_CLK = 32'd50000000, Y_R = 32'd10000,
                     Y_N_MIN = 32'd300;
    parameter integer HALF = 10;
    parameter integer P_END = 200000;

    reg clk = 1'b0, reset_n = 1'b1;
    wire [31:0] xm, xn, xspeed, xfreq, xcycle, xcount;
    wire [31:0] ym, yn, yspeed, yfreq, ycycle, ycount;
    wire xout, yout;
    reg [1023:0] vcd;
    integer pcount = 0;
    reg [31:0] last_xm = 32'hffffffff, last_ym = 32'hffffffff;
    reg last_xout = 1'b0, last_yout = 1'b0;

    scurve_gen #(.V(X_V), .N(X_N), .CRUISE(X_CRUISE), .A_NUM(X_A_NUM), .B_DEN(X_B_DEN), .K(X_K),
                 .F_CLK(X_F_CLK), .R(X_R), .N_MIN(X_N_MIN))
        genx (.clk(clk), .reset_n(reset_n), .m(xm), .n(xn), .speed(xspeed), .freq(xfreq), .cycle(xcycle));
    scurve_gen #(.V(Y_V), .N(Y_N), .CRUISE(Y_CRUISE), .A_NUM(Y_A_NUM), .B_DEN(Y_B_DEN), .K(Y_K),
                 .F_CLK(Y_F_CLK), .R(Y_R), .N_MIN(Y_N_MIN))
        geny (.clk(clk), .reset_n(reset_n), .m(ym), .n(yn), .speed(yspeed), .freq(yfreq), .cycle(ycycle));
    pulse_divider divx (.clk(clk), .reset_n(reset_n), .cycle(xcycle), .clkout(xout), .count(xcount));
    pulse_divider divy (.clk(clk), .reset_n(reset_n), .cycle(ycycle), .clkout(yout), .count(ycount));

    always #HALF clk = ~clk;

    initial begin
        if ($value$plusargs("vcd=%s", vcd)) begin
            $dumpfile(vcd);
            $dumpvars(0, tb_xy);
        end
        #1 reset_n = 1'b0;
        #1 reset_n = 1'b1;
    end

    always @(posedge clk) pcount = pcount + 1;

    always @(negedge clk) begin
        if (xm != last_xm) begin
            $display("SX %0d %0d %0d %0d %0d", xm, xn, xspeed, xfreq, xcycle);
            last_xm = xm;
        end
        if (ym != last_ym) begin
            $display("SY %0d %0d %0d %0d %0d", ym, yn, yspeed, yfreq, ycycle);
            last_ym = ym;
        end
        if (xout != last_xout) begin
            $display("EX %0d %0d", pcount, xout);
            last_xout = xout;
        end
        if (yout != last_yout) begin
            $display("EY %0d %0d", pcount, yout);
            last_yout = yout;
        end
        if (pcount >= P_END) $finish;
    end
endmodule
