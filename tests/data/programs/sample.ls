/PROG  SAMPLE
/ATTR
OWNER		= MNEDITOR;
COMMENT		= "";
LINE_COUNT	= 10;
DEFAULT_GROUP	= 1,*,*,*,*;
/APPL
/MN
   1:J P[1] 100% CNT50    ;
   2:J P[2] 100% FINE    ;
   3:  !hand-written sample ;
   4:L P[3] 250mm/sec CNT50    ;
   5:L P[4:app] 250mm/sec FINE    ;
   6:J P[5] 100% CNT50    ;
   7:J P[6] 100% FINE    ;
   8:L P[7] 250mm/sec CNT50    ;
   9:L P[8] 250mm/sec FINE    ;
  10:L PR[1] 100mm/sec FINE    ;
  11:J P[2] 100% FINE Offset,PR[2]    ;
/POS
P[1]{
   GP1:
	UF : 0, UT : 1,	
	J1=    18.512 deg,	J2=   -98.527 deg,	J3=   100.157 deg,
	J4=     8.326 deg,	J5=    95.804 deg,	J6=    14.923 deg
};
P[2]{
   GP1:
	UF : 0, UT : 1,		CONFIG : 'F U T, 0, 0, 0',
	X =  1474.183  mm,	Y =   255.703  mm,	Z =  1367.362  mm,
	W =  -163.828 deg,	P =    21.277 deg,	R =   156.552 deg
};
P[3]{
   GP1:
	UF : 0, UT : 1,		CONFIG : 'F U T, 0, 0, 0',
	X =  1289.573  mm,	Y =   235.841  mm,	Z =  1443.496  mm,
	W =  -178.886 deg,	P =    15.685 deg,	R =   158.147 deg
};
P[4:"app"]{
   GP1:
	UF : 0, UT : 1,		CONFIG : 'F U T, 0, 0, 0',
	X =  1330.939  mm,	Y =   -39.983  mm,	Z =  1533.124  mm,
	W =  -176.768 deg,	P =    26.506 deg,	R =   155.092 deg
};
P[5]{
   GP1:
	UF : 0, UT : 1,	
	J1=    -8.164 deg,	J2=   -90.310 deg,	J3=   106.325 deg,
	J4=     2.435 deg,	J5=    73.867 deg,	J6=   -17.947 deg
};
P[6]{
   GP1:
	UF : 0, UT : 1,		CONFIG : 'F U T, 0, 0, 0',
	X =  1341.832  mm,	Y =  -205.792  mm,	Z =  1302.408  mm,
	W =  -177.421 deg,	P =    27.167 deg,	R =   153.161 deg
};
P[7]{
   GP1:
	UF : 0, UT : 1,		CONFIG : 'F U T, 0, 0, 0',
	X =  1741.753  mm,	Y =  -218.735  mm,	Z =  1326.847  mm,
	W =  -178.427 deg,	P =    18.868 deg,	R =   160.472 deg
};
P[8]{
   GP1:
	UF : 0, UT : 1,		CONFIG : 'F U T, 0, 0, 0',
	X =  1622.157  mm,	Y =  -434.974  mm,	Z =  1434.860  mm,
	W =  -164.635 deg,	P =    29.550 deg,	R =   171.011 deg
};
/END
